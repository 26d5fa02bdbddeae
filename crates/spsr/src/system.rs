//! The linear system of each depth (ALGORITHM.md §5.5, §6): 1-D integral tables, the vector
//! field V splatted into the tree (§3.6), the screening clusters (§3.7), the divergence
//! constraints `∫∇B_i·V` gathered across depths, and the prolongation/restriction operators.
//!
//! Conventions: "level" `t` is a tree depth, "depth" `d = t − DEPTH_OFFSET` is the unit-cube
//! depth. A node's function index along an axis is its unit offset (`key − 2^d`).

use rayon::prelude::*;

use crate::bspline::{table, Basis, Integrand, Table1D};
use crate::octree::{
    brood_offset, func_index, neighbor_in_row, window_index, BroodRow, BroodSet, Level, NodeRank,
    Octree, DEPTH_OFFSET, NONE,
};
use crate::shared_slice::{split_into, written_zeros, SharedSlice};

/// Inclusive index ranges of a basis at one depth, and range checks.
#[derive(Debug, Clone, Copy)]
pub struct Range {
    /// Lowest index.
    pub lo: i64,
    /// Highest index.
    pub hi: i64,
}

impl Range {
    /// True when all three indices are in range.
    #[inline]
    pub fn contains(&self, i: [i64; 3]) -> bool {
        i.iter().all(|&c| c >= self.lo && c <= self.hi)
    }

    /// True when every index is at least `m` away from both ends.
    #[inline]
    pub fn interior(&self, i: [i64; 3], m: i64) -> bool {
        i.iter().all(|&c| c - self.lo >= m && self.hi - c >= m)
    }
}

/// Prolongation weights: for a fine index `j`, the weights of coarse functions
/// `(j >> 1) − 1 ..= (j >> 1) + 1` in the two-scale expansion.
#[derive(Debug, Clone)]
pub struct Prolong {
    lo: i64,
    w: Vec<[f64; 3]>,
}

impl Prolong {
    /// Builds the weights from `basis.children` at coarse depth `d − 1`.
    pub fn new(basis: Basis, d: u32) -> Self {
        let (lo, hi) = basis.index_range(d);
        let len = (hi - lo + 1).max(0) as usize;
        let mut w = vec![[0.0; 3]; len];
        let (clo, chi) = basis.index_range(d - 1);
        let mut out = [(0i64, 0.0f64); 4];
        for c in clo..=chi {
            let k = basis.children(d - 1, c, &mut out);
            for &(j, wt) in &out[..k] {
                if j < lo || j > hi {
                    continue;
                }
                let o = c - (j >> 1);
                debug_assert!((-1..=1).contains(&o));
                w[(j - lo) as usize][(o + 1) as usize] += wt;
            }
        }
        Self { lo, w }
    }

    /// The first fine index and the rows from it, three weights (offsets −1, 0, 1) each (the
    /// GPU's copy, `crate::gpu`).
    #[cfg_attr(not(feature = "gpu"), allow(dead_code))]
    pub fn rows(&self) -> (i64, &[[f64; 3]]) {
        (self.lo, &self.w)
    }

    /// Weight of coarse `(j >> 1) + o` for fine `j`.
    #[inline]
    pub fn get(&self, j: i64, o: i64) -> f64 {
        self.w
            .get((j - self.lo) as usize)
            .map_or(0.0, |r| r[(o + 1) as usize])
    }
}

/// All 1-D tables needed at one depth.
pub struct DepthTables {
    /// FEM index range.
    pub range: Range,
    /// V index range.
    pub vrange: Range,
    /// ∫B_i B_j, same depth.
    pub mass: Table1D,
    /// ∫B_i' B_j', same depth.
    pub stiff: Table1D,
    /// FEM against the parent depth's FEM functions.
    pub pmass: Table1D,
    /// FEM derivatives against the parent depth's FEM derivatives.
    pub pstiff: Table1D,
    /// FEM values against V functions of the same depth.
    pub vmass: Table1D,
    /// FEM derivatives against V functions of the same depth.
    pub vderiv: Table1D,
    /// FEM values against V functions of the parent depth.
    pub pvmass: Table1D,
    /// FEM derivatives against V functions of the parent depth.
    pub pvderiv: Table1D,
    /// FEM prolongation from the parent depth.
    pub prolong: Prolong,
    /// V prolongation from the parent depth.
    pub vprolong: Prolong,
    /// The interior 3-D stiffness stencil, by window index.
    pub stencil: [f64; 125],
    /// Interior parent stiffness stencils, by child parity (x bit 0) and parent window index.
    pub pstencil: Box<[[f64; 125]; 8]>,
    /// Interior parent V stencils, by child parity, component and parent window index.
    pub pvstencil: Box<[[[f64; 125]; 3]; 8]>,
    /// By child parity, the parent window indices where `pstencil` or `pvstencil` is nonzero.
    pub pnonzero: [Vec<u8>; 8],
    /// The entries of `pnonzero` where `pstencil` is nonzero, in the same order: the parent
    /// window of the coarser solution's coupling alone. (Issue 20: at degree 1 the V stencils
    /// reach further than the stiffness ones, and most rows have no coarser V near them.)
    pub psnonzero: [Vec<u8>; 8],
    /// FEM values of this depth against V functions one depth finer.
    pub cvmass: CoarseFine,
    /// FEM derivatives of this depth against V functions one depth finer.
    pub cvderiv: CoarseFine,
}

/// 1-D integrals between the FEM functions `I` of one depth and the V functions `o` one depth
/// finer, for offsets `o − 2I ∈ [−3, 4]`. Built exactly from the two-scale relation,
/// `∫B_I^(k) B_o = Σ_j c_Ij ∫B_{j}^(k) B_o`, with the same-depth tables of the finer depth.
#[derive(Debug, Clone)]
pub struct CoarseFine {
    lo: i64,
    rows: Vec<[f64; 8]>,
}

impl CoarseFine {
    fn new(fem: Basis, d: u32, fine: &Table1D) -> Self {
        let (lo, hi) = fem.index_range(d);
        let mut out = [(0i64, 0.0f64); 4];
        let rows = (lo..=hi)
            .map(|i| {
                let k = fem.children(d, i, &mut out);
                let mut row = [0.0; 8];
                for (slot, r) in row.iter_mut().enumerate() {
                    let o = 2 * i + slot as i64 - 3;
                    *r = out[..k].iter().map(|&(j, c)| c * fine.get(j, o - j)).sum();
                }
                row
            })
            .collect();
        Self { lo, rows }
    }

    /// The lowest coarse index and the rows from it on, eight offsets `k = −3..=4` each, for
    /// the GPU's copy of [`CoarseFine::get`] (`gpu/kernels.cu`).
    #[cfg(feature = "gpu")]
    pub fn rows(&self) -> (i64, &[[f64; 8]]) {
        (self.lo, &self.rows)
    }

    /// Entry for coarse index `i` and offset `k = o − 2i` (0 outside `[−3, 4]` or the range).
    #[inline]
    pub fn get(&self, i: i64, k: i64) -> f64 {
        if !(-3..=4).contains(&k) {
            return 0.0;
        }
        self.rows
            .get((i - self.lo) as usize)
            .map_or(0.0, |r| r[(k + 3) as usize])
    }
}

impl DepthTables {
    /// Builds the tables of unit depth `d ≥ 1`.
    pub fn new(fem: Basis, vb: Basis, d: u32) -> Self {
        let (lo, hi) = fem.index_range(d);
        let (vlo, vhi) = vb.index_range(d);
        let same = |a, b, i| table(a, b, d, false, i);
        let par = |a, b, i| table(a, b, d, true, i);
        let mass = same(fem, fem, Integrand::ValueValue);
        let stiff = same(fem, fem, Integrand::DerivDeriv);
        let mid = (lo + hi) / 2;
        let mut stencil = [0.0; 125];
        for (w, s) in stencil.iter_mut().enumerate() {
            let o = [
                (w % 5) as i64 - 2,
                ((w / 5) % 5) as i64 - 2,
                (w / 25) as i64 - 2,
            ];
            *s = stiffness_3d(&mass, &stiff, [mid; 3], o);
        }
        let vmass = same(fem, vb, Integrand::ValueValue);
        let vderiv = same(fem, vb, Integrand::DerivValue);
        let pmass = par(fem, fem, Integrand::ValueValue);
        let pstiff = par(fem, fem, Integrand::DerivDeriv);
        let pvmass = par(fem, vb, Integrand::ValueValue);
        let pvderiv = par(fem, vb, Integrand::DerivValue);
        let mut pstencil = Box::new([[0.0; 125]; 8]);
        let mut pvstencil = Box::new([[[0.0; 125]; 3]; 8]);
        let even = mid - (mid & 1);
        for w in 0..125 {
            let o = [
                (w % 5) as i64 - 2,
                ((w / 5) % 5) as i64 - 2,
                (w / 25) as i64 - 2,
            ];
            let vector = |m: &Table1D, dv: &Table1D, i: [i64; 3]| {
                let mm = [m.get(i[0], o[0]), m.get(i[1], o[1]), m.get(i[2], o[2])];
                let dd = [dv.get(i[0], o[0]), dv.get(i[1], o[1]), dv.get(i[2], o[2])];
                [
                    dd[0] * mm[1] * mm[2],
                    mm[0] * dd[1] * mm[2],
                    mm[0] * mm[1] * dd[2],
                ]
            };
            for c in 0..8usize {
                let i = [
                    even + (c & 1) as i64,
                    even + ((c >> 1) & 1) as i64,
                    even + ((c >> 2) & 1) as i64,
                ];
                pstencil[c][w] = stiffness_3d(&pmass, &pstiff, i, o);
                let v = vector(&pvmass, &pvderiv, i);
                for a in 0..3 {
                    pvstencil[c][a][w] = v[a];
                }
            }
        }
        let cvmass = CoarseFine::new(fem, d, &table(fem, vb, d + 1, false, Integrand::ValueValue));
        let cvderiv = CoarseFine::new(fem, d, &table(fem, vb, d + 1, false, Integrand::DerivValue));
        let pnonzero: [Vec<u8>; 8] = std::array::from_fn(|c| {
            (0..125u8)
                .filter(|&w| {
                    let w = usize::from(w);
                    pstencil[c][w] != 0.0 || pvstencil[c].iter().any(|a| a[w] != 0.0)
                })
                .collect()
        });
        let psnonzero = std::array::from_fn(|c| {
            pnonzero[c]
                .iter()
                .copied()
                .filter(|&w| pstencil[c][usize::from(w)] != 0.0)
                .collect()
        });
        Self {
            pnonzero,
            psnonzero,
            cvmass,
            cvderiv,
            range: Range { lo, hi },
            vrange: Range { lo: vlo, hi: vhi },
            pmass,
            pstiff,
            vmass,
            vderiv,
            pvmass,
            pvderiv,
            pstencil,
            pvstencil,
            prolong: Prolong::new(fem, d),
            vprolong: Prolong::new(vb, d),
            mass,
            stiff,
            stencil,
        }
    }

    /// True when row `i` and its whole window are far enough from the boundary that the
    /// precomputed interior stencils apply.
    #[inline]
    pub fn is_interior(&self, i: [i64; 3]) -> bool {
        self.range.interior(i, 4)
    }

    /// Stiffness entry `∫∇B_i·∇B_j` between function `i` and `i + o` (same depth).
    #[inline]
    pub fn stiffness(&self, i: [i64; 3], o: [i64; 3]) -> f64 {
        stiffness_3d(&self.mass, &self.stiff, i, o)
    }
}

/// `∫∇B_i·∇B_{i+o}` of the tensor-product functions from the 1-D mass and stiffness tables.
#[inline]
pub(crate) fn stiffness_3d(mass: &Table1D, stiff: &Table1D, i: [i64; 3], o: [i64; 3]) -> f64 {
    let m = [
        mass.get(i[0], o[0]),
        mass.get(i[1], o[1]),
        mass.get(i[2], o[2]),
    ];
    let k = [
        stiff.get(i[0], o[0]),
        stiff.get(i[1], o[1]),
        stiff.get(i[2], o[2]),
    ];
    k[0] * m[1] * m[2] + m[0] * k[1] * m[2] + m[0] * m[1] * k[2]
}

/// `K` same-depth 5×5×5 stencils regrouped by neighbouring brood (issue 20). For a node at
/// child position `c`, `rows[c]` lists the slots of the broods its window reaches and, for
/// each, the stencils' entries for that brood's eight nodes (zero outside the window). A row
/// is then at most 27 reads of eight contiguous values, summed lane by lane, instead of 125
/// scattered reads summed one after another.
pub struct BroodStencil<const K: usize> {
    rows: [Vec<(u8, [[f64; 8]; K])>; 8],
}

impl<const K: usize> BroodStencil<K> {
    /// The stencils, indexed by [`window_index`].
    pub fn new(stencils: [&[f64; 125]; K]) -> Self {
        let rows = std::array::from_fn(|c| {
            let mut row = Vec::new();
            for slot in 0..27u8 {
                let mut coef = [[0.0; 8]; K];
                for k in 0..8 {
                    let o = brood_offset(c, slot, k);
                    if o.iter().all(|v| v.abs() <= 2) {
                        for (e, st) in coef.iter_mut().zip(&stencils) {
                            e[k] = st[window_index(o)];
                        }
                    }
                }
                if coef.iter().flatten().any(|&e| e != 0.0) {
                    row.push((slot, coef));
                }
            }
            row
        });
        BroodStencil { rows }
    }

    /// Per child position, the brood slots of its row and each slot's eight coefficients (of
    /// the first stencil), for the GPU's copy of the sum (`gpu/kernels.cu`).
    #[cfg(feature = "gpu")]
    pub fn rows(&self) -> impl Iterator<Item = &[(u8, [[f64; 8]; K])]> {
        self.rows.iter().map(|r| r.as_slice())
    }

    /// `Σ_j Σ_k S_k[n, j] y_k[j]` over the window of node `n` of `level`, where `brood(b)`
    /// gives the `K` values of brood `b`'s eight nodes. Lane `l` sums the `l`-th nodes of the
    /// broods (`L` says in which vectors); the lanes are added pairwise in a fixed order.
    #[inline(always)]
    pub fn row<L: Lanes>(
        &self,
        nbrs: &BroodRow,
        n: u32,
        brood: impl Fn(u32) -> [[f64; 8]; K],
    ) -> f64 {
        let mut acc = [0.0f64; 8];
        for (slot, coef) in &self.rows[(n & 7) as usize] {
            let b = nbrs[usize::from(*slot)];
            if b == NONE {
                continue;
            }
            let v = brood(b);
            for (ck, vk) in coef.iter().zip(&v) {
                L::multiply_add(&mut acc, ck, vk);
            }
        }
        ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]))
    }
}

/// Eight lanes of `acc += c · v`, each lane one multiplication then one addition (never
/// fused), so every implementation gives the same bits.
pub trait Lanes {
    fn multiply_add(acc: &mut [f64; 8], c: &[f64; 8], v: &[f64; 8]);
}

/// [`Lanes`] as plain Rust: the compiler picks the vectors (two lanes at a time on x86-64's
/// baseline SSE2).
pub struct PlainLanes;

impl Lanes for PlainLanes {
    #[inline(always)]
    fn multiply_add(acc: &mut [f64; 8], c: &[f64; 8], v: &[f64; 8]) {
        for l in 0..8 {
            acc[l] += c[l] * v[l];
        }
    }
}

/// [`Lanes`] four at a time in AVX 256-bit vectors. Only for code compiled with AVX enabled
/// and run where the processor has it (`solver::Wide`): the compiler then inlines the
/// intrinsics.
#[cfg(target_arch = "x86_64")]
pub struct AvxLanes;

#[cfg(target_arch = "x86_64")]
impl Lanes for AvxLanes {
    #[inline(always)]
    fn multiply_add(acc: &mut [f64; 8], c: &[f64; 8], v: &[f64; 8]) {
        use std::arch::x86_64::{_mm256_add_pd, _mm256_loadu_pd, _mm256_mul_pd, _mm256_storeu_pd};
        for h in [0, 4] {
            // SAFETY: the pointers cover four f64 each (h ≤ 4 of 8); AVX is there (above).
            unsafe {
                let p = _mm256_mul_pd(
                    _mm256_loadu_pd(c.as_ptr().add(h)),
                    _mm256_loadu_pd(v.as_ptr().add(h)),
                );
                let a = _mm256_add_pd(_mm256_loadu_pd(acc.as_ptr().add(h)), p);
                _mm256_storeu_pd(acc.as_mut_ptr().add(h), a);
            }
        }
    }
}

/// Screening clusters of one level (ALGORITHM.md §3.7).
#[derive(Debug, Default, Clone)]
pub struct Clusters {
    /// Cluster index of each node of the level.
    pub of_node: NodeRank,
    /// Node of each cluster.
    pub node: Vec<u32>,
    /// Weighted mean position, unit-cube coordinates, stored in single precision as the
    /// reference stores its screening samples' positions (issue 20: 12 bytes a cluster; the
    /// basis values at it, `vals`, come from the position in double precision).
    pub pos: Vec<[f32; 3]>,
    /// Screening weight ω = α Ā 2^d W.
    pub omega: Vec<f64>,
    /// Per axis, the first FEM index whose support contains the position, modulo 256: every
    /// index a cluster meets lies within a few of it, and recovers it ([`Clusters::first`]).
    /// (Issue 20: a quarter of the bytes of full indices, and the clusters are a third of
    /// the solve's memory.)
    first: Vec<[u8; 3]>,
    /// Per axis, the values of the `degree + 1` functions from `first`, single precision:
    /// `3 (degree + 1)` per cluster, axis by axis.
    vals: Vec<f32>,
    /// Values per axis, `degree + 1`.
    per_axis: usize,
}

impl Clusters {
    /// Number of clusters.
    pub fn len(&self) -> usize {
        self.node.len()
    }

    /// Per axis, the first FEM index of cluster `c`'s window, from any index `near` within
    /// 127 of it (a function the cluster touches, or the cluster's own node's).
    #[inline]
    pub fn first(&self, c: usize, near: [i64; 3]) -> [i64; 3] {
        let f = self.first[c];
        std::array::from_fn(|a| near[a] + i64::from(offset_mod_256(f[a], near[a])))
    }

    /// Value of function `k` (from [`Clusters::first`]) along axis `a` at cluster `c`.
    #[inline]
    pub fn axis_value(&self, c: usize, a: usize, k: usize) -> f32 {
        self.vals[(3 * c + a) * self.per_axis + k]
    }

    /// Value of FEM function `i` at cluster `c`.
    #[inline]
    pub fn basis_value(&self, c: usize, i: [i64; 3], degree: u8) -> f64 {
        let f = self.first[c];
        let mut r = 1.0;
        for a in 0..3 {
            // `i − first`, which is small for every function a cluster is asked about.
            let k = -i64::from(offset_mod_256(f[a], i[a]));
            if k < 0 || k > i64::from(degree) {
                return 0.0;
            }
            r *= f64::from(self.axis_value(c, a, k as usize));
        }
        r
    }

    /// Every cluster's first index per axis in full, from its node's key (the GPU's layout).
    #[cfg(feature = "gpu")]
    pub fn first_indices(&self, level: &Level, d: u32) -> Vec<[i32; 3]> {
        (0..self.len())
            .into_par_iter()
            .map(|c| {
                let own = func_index(level.key(self.node[c]), d);
                self.first(c, own).map(|f| f as i32)
            })
            .collect()
    }

    /// Every cluster's values as three per axis, zero past `degree + 1` (the GPU's layout).
    #[cfg(feature = "gpu")]
    pub fn values_3x3(&self) -> Vec<[[f32; 3]; 3]> {
        (0..self.len())
            .into_par_iter()
            .map(|c| {
                std::array::from_fn(|a| {
                    std::array::from_fn(|k| {
                        if k < self.per_axis {
                            self.axis_value(c, a, k)
                        } else {
                            0.0
                        }
                    })
                })
            })
            .collect()
    }
}

/// `stored − near` for an index stored modulo 256, exact while the two are within 127.
#[inline]
fn offset_mod_256(stored: u8, near: i64) -> i8 {
    stored.wrapping_sub(near as u8) as i8
}

/// Builds the clusters of every level `≥ base level` from the samples' deepest nodes.
/// `leaf_of` gives, per sample, its deepest node `(level, node)`; `weights`/`positions` the
/// sample data. Output is indexed by level.
pub fn build_clusters(
    tree: &Octree,
    fem: Basis,
    base_level: u32,
    leaf_of: &[(u32, u32)],
    positions: &[[f64; 3]],
    weights: &[f64],
    omega_scale: f64,
) -> Vec<Clusters> {
    let mut out: Vec<Clusters> = (0..tree.levels.len())
        .map(|_| Clusters::default())
        .collect();
    for_each_cluster_sum(
        tree,
        base_level,
        leaf_of,
        positions,
        weights,
        |t, merged| {
            out[t as usize] = level_clusters(tree, fem, t, merged, omega_scale);
        },
    );
    out
}

/// The samples' weight `W` and weighted position sum `W·p` per node of every level `≥ base
/// level`, finest level first: `f(level, sums)` with the sums sorted by node. A node's sums
/// are those of its children's plus the samples whose deepest node it is. The sums of disjoint
/// sets of samples add, which is how slabs combine their clusters.
pub fn for_each_cluster_sum(
    tree: &Octree,
    base_level: u32,
    leaf_of: &[(u32, u32)],
    positions: &[[f64; 3]],
    weights: &[f64],
    mut f: impl FnMut(u32, &[ClusterSum]),
) {
    let nlev = tree.levels.len();
    // Entries (node, W, W·p) per level, filled from the samples, merged, then pushed up.
    let mut pending = sample_sums_per_level(nlev, leaf_of, positions, weights);
    for t in (base_level as usize..nlev).rev() {
        let merged = merge_cluster_sums(std::mem::take(&mut pending[t]));
        if t > base_level as usize {
            let up = merged
                .par_iter()
                .map(|&(n, w, wp)| (tree.parent(t as u32, n), w, wp));
            pending[t - 1].par_extend(up);
        }
        f(t as u32, &merged);
    }
}

/// Samples per task when they are sorted into levels.
const SAMPLE_CHUNK: usize = 1 << 16;

/// Each sample's `(node, W, W·p)` in the list of its deepest node's level, in sample order.
/// Chunks of samples are counted per level, then each fills its own stretch of every list
/// (stretches in chunk order, so the order, which fixes the order of the later sums, is the
/// serial one), in parallel and without a second copy of the lists.
fn sample_sums_per_level(
    nlev: usize,
    leaf_of: &[(u32, u32)],
    positions: &[[f64; 3]],
    weights: &[f64],
) -> Vec<Vec<ClusterSum>> {
    let counts: Vec<Vec<usize>> = leaf_of
        .par_chunks(SAMPLE_CHUNK)
        .map(|chunk| {
            let mut count = vec![0; nlev];
            for &(t, _) in chunk {
                count[t as usize] += 1;
            }
            count
        })
        .collect();
    let mut out: Vec<Vec<ClusterSum>> = (0..nlev)
        .map(|t| {
            let len = counts.iter().map(|c| c[t]).sum();
            let mut list = Vec::with_capacity(len);
            list.par_extend(rayon::iter::repeat_n((0, 0.0, [0.0; 3]), len));
            list
        })
        .collect();
    // The stretches of chunk `c`: one slice per level.
    let mut stretches: Vec<Vec<&mut [ClusterSum]>> = counts.iter().map(|_| Vec::new()).collect();
    for (t, list) in out.iter_mut().enumerate() {
        for (own, mine) in stretches
            .iter_mut()
            .zip(split_into(list, counts.iter().map(|c| c[t])))
        {
            own.push(mine);
        }
    }
    stretches
        .into_par_iter()
        .zip(leaf_of.par_chunks(SAMPLE_CHUNK))
        .enumerate()
        .for_each(|(c, (mut own, chunk))| {
            let mut fill = vec![0; nlev];
            for (i, &(t, n)) in chunk.iter().enumerate() {
                let s = c * SAMPLE_CHUNK + i;
                let (w, p) = (weights[s], positions[s]);
                let t = t as usize;
                own[t][fill[t]] = (n, w, [w * p[0], w * p[1], w * p[2]]);
                fill[t] += 1;
            }
        });
    out
}

/// The sums of each node, added in the order given (the sort is stable), sorted by node.
/// The sort and the sums run in parallel: each node's entries are added in the given order
/// by one task, so the sums do not depend on the thread count. On one thread the standard
/// sort, quicker on the few long sorted runs these lists hold, gives the same order (both
/// sorts are stable).
pub fn merge_cluster_sums(mut entries: Vec<ClusterSum>) -> Vec<ClusterSum> {
    if rayon::current_num_threads() > 1 {
        entries.par_sort_by_key(|e| e.0);
    } else {
        entries.sort_by_key(|e| e.0);
    }
    let starts: Vec<usize> = (0..entries.len())
        .into_par_iter()
        .filter(|&k| k == 0 || entries[k].0 != entries[k - 1].0)
        .collect();
    starts
        .par_iter()
        .enumerate()
        .map(|(g, &s)| {
            let end = starts.get(g + 1).copied().unwrap_or(entries.len());
            let mut sum = entries[s];
            for &(_, w, wp) in &entries[s + 1..end] {
                sum.1 += w;
                for a in 0..3 {
                    sum.2[a] += wp[a];
                }
            }
            sum
        })
        .collect()
}

/// One cluster's sums before it is finished: `(node, W, W·p)`.
pub type ClusterSum = (u32, f64, [f64; 3]);

/// The clusters of level `t` from their sums (sorted by node), with screening weights
/// `omega_scale · 2^d · W`.
pub fn level_clusters(
    tree: &Octree,
    fem: Basis,
    t: u32,
    merged: &[ClusterSum],
    omega_scale: f64,
) -> Clusters {
    let d = t - DEPTH_OFFSET;
    let scale = omega_scale * (1i64 << d) as f64;
    let per_axis = usize::from(fem.degree.get()) + 1;
    // Each cluster is finished on its own, in parallel, its windows found once (the first
    // index and the values come from the same window); `unzip` keeps the order.
    let mut vals = vec![0.0f32; 3 * per_axis * merged.len()];
    let ((node, pos), (omega, first)): ((Vec<_>, Vec<_>), (Vec<_>, Vec<_>)) = vals
        .par_chunks_mut(3 * per_axis)
        .zip(merged)
        .map(|(out, &(n, w, wp))| {
            let p = [wp[0] / w, wp[1] / w, wp[2] / w];
            let first = window_values(fem, d, p, out);
            ((n, p.map(|x| x as f32)), (scale * w, first))
        })
        .unzip();
    Clusters {
        of_node: NodeRank::new(tree.levels[t as usize].len(), merged.iter().map(|e| e.0)),
        node,
        pos,
        omega,
        first,
        vals,
        per_axis,
    }
}

/// Per axis, the values at `p` of the `degree + 1` functions of depth `d` from the first
/// ([`Clusters::axis_value`]), in single precision, into `out` (`degree + 1` per axis); returns
/// the first function's index per axis modulo 256 ([`Clusters::first`]).
fn window_values(fem: Basis, d: u32, p: [f64; 3], out: &mut [f32]) -> [u8; 3] {
    let mut first = [0u8; 3];
    for (a, out) in out.chunks_mut(out.len() / 3).enumerate() {
        let win = fem.window(d, p[a]);
        first[a] = win.first as u8;
        for (o, v) in out.iter_mut().zip(win.values) {
            *o = v as f32;
        }
    }
    first
}

/// Per-axis offsets (relative to a function's own cell) of the cells whose cluster can touch
/// the function: `o ∈ i − {0,1}` for degree 1, `o ∈ i + {−1,0,1}` for degree 2.
pub fn cluster_offsets(degree: u8) -> &'static [i64] {
    if degree == 1 {
        &[-1, 0]
    } else {
        &[-1, 0, 1]
    }
}

/// Divergence constraints of level `t` (ALGORITHM.md §6), fine to coarse. Returns
/// `(G_t, T_t)` where `G_t[i] = ∫∇B_i·V_{>d}` (V of all finer depths; empty when there is
/// none, as at the finest level) and `T_t = G_t + ∫∇B_i·V_d` (adding the same depth).
///
/// `G_t` is the restriction of `G_{t+1}` (V two or more depths finer: exact, because the
/// conforming windows guarantee every child function that such V touches) plus the V of the
/// next depth applied directly through the coarse-FEM × fine-V tables: restricting the next
/// depth's own constraints instead would miss the children functions that have no node.
pub fn divergence_constraints(
    tree: &Octree,
    t: u32,
    tab: &DepthTables,
    fem: Basis,
    v: &[[f32; 3]],
    v_finer: &[[f32; 3]],
    g_finer: Option<&[f64]>,
) -> (Vec<f64>, Vec<f32>) {
    let d = t - DEPTH_OFFSET;
    let level = &tree.levels[t as usize];
    let next = tree.levels.get(t as usize + 1);
    // `G_t` starts as the next depth's V pushed into this level, and the restriction of
    // `G_{t+1}` is added to it in place: one array of the level's doubles instead of two
    // (issue 20: at the second-finest level they were the largest arrays made while V is
    // alive, where the run's memory peaks).
    let mut g = match next {
        Some(next) if !v_finer.is_empty() => push_finer_v(level, next, d, tab, v_finer),
        _ => Vec::new(),
    };
    // An empty `G_{t+1}` is the zero one (see the end).
    let g_finer = g_finer.filter(|g| !g.is_empty());
    let reach = match (g_finer, next) {
        (Some(gf), Some(next)) => sparse_reach(level, next, gf),
        _ => None,
    };
    if g.is_empty() && g_finer.is_some() {
        g = written_zeros(level.len());
    }
    let with_v = broods_with_v(v);
    // Brood `b`'s rows: `T_t` of its eight nodes, and `G_t` (`g`, the pushed V on entry) where
    // it is kept. The same depth's V term is summed for the whole brood ([`v_brood_term`])
    // where a brood around it has a nonzero V; where none has, the term is zero and left out.
    let rows = |b: u32, g: &mut [f64], t: &mut [f32]| {
        let nbrs = level.brood_row(b);
        let i0 = func_index(level.key(8 * b), d);
        let vterm =
            (!v.is_empty() && any_with_v(&nbrs, &with_v)).then(|| v_brood_term(tab, i0, &nbrs, v));
        for k in 0..8usize {
            let n = 8 * b + k as u32;
            let i: [i64; 3] = std::array::from_fn(|a| i0[a] + ((k >> a) & 1) as i64);
            if !tab.range.contains(i) {
                if let Some(g) = g.get_mut(k) {
                    *g = 0.0;
                }
                t[k] = 0.0;
                continue;
            }
            let mut gn = g.get(k).copied().unwrap_or(0.0);
            if let (Some(gf), Some(next)) = (g_finer, next) {
                if reach.as_ref().is_none_or(|r| r.contains(b)) {
                    gn += restrict_one(tree, level, next, fem, d, n, i, gf);
                }
            }
            if let Some(g) = g.get_mut(k) {
                *g = gn;
            }
            let b = vterm.map_or(gn, |vt| gn + vt[k]);
            t[k] = b as f32;
        }
    };
    let mut t_out = vec![0.0f32; level.len()];
    if g.is_empty() {
        // No finer V: `G_t` is zero, and is not stored (at the finest level it would be the
        // largest array alive while the constraints are made).
        t_out.par_chunks_mut(8).enumerate().for_each(|(b, t)| {
            rows(b as u32, &mut [], t);
        });
    } else {
        (g.par_chunks_mut(8).zip(t_out.par_chunks_mut(8)))
            .enumerate()
            .for_each(|(b, (g, t))| rows(b as u32, g, t));
    }
    (g, t_out)
}

/// Where `G_{t+1}` (`g_finer`, on `next`) is zero on all but a few of its broods, the broods of
/// `level` whose rows reach one of the others: elsewhere every term of the restriction
/// ([`restrict_one`]) is zero, and the sum, which starts at +0 and to which a zero term adds
/// nothing, is +0 whether they are added or not. `None` (restrict everywhere) otherwise, where
/// finding them would cost about what it saves. Where the samples hardly reach the deepest
/// depth, the level above it has a `G` that is zero but near those few nodes (issue 20:
/// spot_1m at depth 11, 1,792 nodes at depth 11 under 8.3 million at depth 10).
fn sparse_reach(level: &Level, next: &Level, g_finer: &[f64]) -> Option<BroodSet> {
    let nonzero: Vec<u32> = g_finer
        .par_chunks(8)
        .enumerate()
        .filter(|(_, g)| g.iter().any(|&x| x != 0.0))
        .map(|(c, _)| next.brood_parent[c])
        .collect();
    (4 * nonzero.len() < next.broods()).then(|| level.broods_reaching(&nonzero))
}

/// `∫∇B_i · V_d` for the eight functions `i = i0 + k` of one brood (child position `k`), from
/// the same depth's V of the 27 broods around it (`nbrs`). Each term is a product of 1-D
/// integrals, so the window's 5×5×5 sum is taken one axis at a time over the 6×6×6 nodes of
/// the 27 broods: x, then y, then z, each node's sum in one fixed order (the GPU's
/// `constraint_rows` takes the same steps for one node). Near the boundary the 1-D tables of
/// each index are used, so the same code serves every function. (Issue 20: a quarter of the
/// multiplications of the 3-D stencils, each V read once per brood instead of once per node.)
pub(crate) fn v_brood_term(
    tab: &DepthTables,
    i0: [i64; 3],
    nbrs: &BroodRow,
    v: &[[f32; 3]],
) -> [f64; 8] {
    // Per axis and child bit: the value and derivative tables at offsets −2..=2.
    let mut m = [[[0.0f64; 5]; 2]; 3];
    let mut dv = [[[0.0f64; 5]; 2]; 3];
    for a in 0..3 {
        for bit in 0..2 {
            for o in 0..5 {
                m[a][bit][o] = tab.vmass.get(i0[a] + bit as i64, o as i64 - 2);
                dv[a][bit][o] = tab.vderiv.get(i0[a] + bit as i64, o as i64 - 2);
            }
        }
    }
    // The 6×6×6 nodes' V by component, z, y, x (absent nodes zero).
    let mut vl = [[[[0.0f64; 6]; 6]; 6]; 3];
    for (slot, &q) in nbrs.iter().enumerate() {
        if q == NONE {
            continue;
        }
        let s = [slot % 3, slot / 3 % 3, slot / 9];
        let nodes = &v[8 * q as usize..8 * q as usize + 8];
        for (k, vk) in nodes.iter().enumerate() {
            let [x, y, z] = std::array::from_fn(|a| 2 * s[a] + ((k >> a) & 1));
            for comp in 0..3 {
                vl[comp][z][y][x] = f64::from(vk[comp]);
            }
        }
    }
    // Along x, per node bit bx: V's x component through the derivative, y and z through
    // the value.
    let mut tx = [[[0.0f64; 2]; 6]; 6];
    let mut ty = [[[0.0f64; 2]; 6]; 6];
    let mut tz = [[[0.0f64; 2]; 6]; 6];
    for z in 0..6 {
        for y in 0..6 {
            for bx in 0..2 {
                let (mut sx, mut sy, mut sz) = (0.0, 0.0, 0.0);
                for o in 0..5 {
                    sx += vl[0][z][y][bx + o] * dv[0][bx][o];
                    sy += vl[1][z][y][bx + o] * m[0][bx][o];
                    sz += vl[2][z][y][bx + o] * m[0][bx][o];
                }
                (tx[z][y][bx], ty[z][y][bx], tz[z][y][bx]) = (sx, sy, sz);
            }
        }
    }
    // Along y: the x and y components together (y's through the derivative), z's apart.
    let mut uxy = [[[0.0f64; 2]; 2]; 6];
    let mut uz = [[[0.0f64; 2]; 2]; 6];
    for z in 0..6 {
        for by in 0..2 {
            for bx in 0..2 {
                let (mut sxy, mut sz) = (0.0, 0.0);
                for o in 0..5 {
                    let y = by + o;
                    sxy += tx[z][y][bx] * m[1][by][o] + ty[z][y][bx] * dv[1][by][o];
                    sz += tz[z][y][bx] * m[1][by][o];
                }
                (uxy[z][by][bx], uz[z][by][bx]) = (sxy, sz);
            }
        }
    }
    // Along z: z's component through the derivative.
    std::array::from_fn(|k| {
        let (bx, by, bz) = (k & 1, (k >> 1) & 1, (k >> 2) & 1);
        let mut s = 0.0;
        for o in 0..5 {
            let z = bz + o;
            s += uxy[z][by][bx] * m[2][bz][o] + uz[z][by][bx] * dv[2][bz][o];
        }
        s
    })
}

/// For each brood of a level, whether its V (one per node; may be empty) is nonzero
/// anywhere. At the deepest level every brood has V (the others were clipped); one level
/// up few do (a tenth on bunny_1m at depth 9, and half of that level's broods have none
/// around them), and the coarser levels none (their samples' V is pushed to them,
/// `push_finer_v`).
pub(crate) fn broods_with_v(v: &[[f32; 3]]) -> Vec<bool> {
    v.par_chunks(8)
        .map(|nodes| nodes.iter().any(|x| *x != [0.0; 3]))
        .collect()
}

/// Whether any brood of `row` has V ([`broods_with_v`]).
#[inline]
pub(crate) fn any_with_v(row: &BroodRow, with_v: &[bool]) -> bool {
    row.iter()
        .any(|&q| q != NONE && with_v.get(q as usize).is_some_and(|&x| x))
}

/// `∫∇B_I · V_{d+1}` for every FEM function `I` of level `t` (depth `d`), pushed from each
/// brood of the next level with a nonzero V to the 5×5×5 coarse functions around its parent
/// that its eight children overlap ([`push_brood`]), tile by tile ([`brood_tiles`]): the
/// tiles of a colour in parallel, each tile's broods in order. (Issue 20: colouring single
/// broods by their parent's key modulo 5 made 125 passes over the level, each touching all of
/// it; bunny_1m at depth 9: 0.80 s → 0.28 s.)
fn push_finer_v(
    level: &Level,
    next: &Level,
    d: u32,
    tab: &DepthTables,
    v_finer: &[[f32; 3]],
) -> Vec<f64> {
    push_to_parent_windows(level, next, |b| {
        let vf: &[[f32; 3]; 8] = v_finer[8 * b as usize..8 * b as usize + 8]
            .try_into()
            .expect("eight nodes");
        if vf.iter().all(|v| *v == [0.0; 3]) {
            return None;
        }
        let ip = func_index(level.key(next.brood_parent[b as usize]), d);
        Some(push_brood(tab, ip, vf))
    })
}

/// Sums, for every node of `parent_level`, what the broods of `level` push into their
/// parents' 5×5×5 windows: `window(b)` gives brood `b`'s terms by window index (`None`:
/// nothing), tile by tile ([`brood_tiles`]): the colours one after another, the tiles of a
/// colour in parallel and each tile's broods in order, so every sum is taken in an order that
/// does not depend on the thread count. Zero terms and absent nodes are skipped.
pub(crate) fn push_to_parent_windows(
    parent_level: &Level,
    level: &Level,
    window: impl Fn(u32) -> Option<[f64; 125]> + Sync,
) -> Vec<f64> {
    // Written first (`written_zeros`): the tiles' sums read before they write. Where the
    // finer level is sparse, pages that no window reaches become resident too: on spot_1m at
    // depth 11 one of two runs peaked 5 MB higher (641 against 636 MB), for divergence
    // constraints 0.3 s faster.
    let mut g = written_zeros(parent_level.len());
    let gs = SharedSlice::new(&mut g);
    for colour in &brood_tiles(parent_level, level) {
        colour.par_iter().for_each(|range| {
            for b in range.clone() {
                let Some(out) = window(b) else {
                    continue;
                };
                let p = level.brood_parent[b as usize];
                let row = parent_level.brood_row(p >> 3);
                for (w, &val) in out.iter().enumerate() {
                    if val == 0.0 {
                        continue;
                    }
                    let q = neighbor_in_row(&row, p, w);
                    if q == NONE {
                        continue;
                    }
                    // SAFETY: within one colour, only this tile's task writes the windows of
                    // its broods' parents (see [`brood_tiles`]).
                    unsafe { gs.set(q as usize, gs.get(q as usize) + val) };
                }
            }
        });
    }
    g
}

/// The broods of `level` cut into tiles: the broods whose parents (in `parent_level`) lie in
/// one aligned block of `TILE³` parent cells, contiguous in the level's Morton order. A
/// parent window reaches two cells beyond its parent, so the windows of two tiles whose block
/// coordinates differ by two or more along some axis never overlap; the tiles are coloured by
/// their block coordinates modulo 2 per axis. Per colour, the brood ranges of its tiles in the
/// level's order: pushing the colours one after another, the tiles of a colour in parallel
/// and each tile's broods in order, takes every sum in an order that does not depend on the
/// thread count, and keeps a task's reads and writes within one neighbourhood of the tree.
/// The GPU pushes the same tiles in the same order (`solver::device`).
pub(crate) fn brood_tiles(parent_level: &Level, level: &Level) -> Vec<Vec<std::ops::Range<u32>>> {
    const TILE: u32 = 8;
    let mut colours: Vec<Vec<std::ops::Range<u32>>> = vec![Vec::new(); 8];
    let broods = (level.len() / 8) as u32;
    let tile_of = |b: u32| {
        parent_level
            .key(level.brood_parent[b as usize])
            .map(|k| k / TILE)
    };
    let mut b = 0;
    while b < broods {
        let tile = tile_of(b);
        let mut e = b + 1;
        while e < broods && tile_of(e) == tile {
            e += 1;
        }
        let colour = (tile[0] % 2 + 2 * (tile[1] % 2) + 4 * (tile[2] % 2)) as usize;
        colours[colour].push(b..e);
        b = e;
    }
    colours
}

/// `Σ_c ∫∇B_I · V_c` over the eight children `c` of a parent with function index `ip`, for
/// the 5×5×5 coarse functions `I = ip + r`, `r ∈ [−2, 2]³`, by window index. Each term is a
/// product of 1-D integrals (`∂_x B·B^V` × `B·B^V` × `B·B^V` for V's x component, and so on),
/// so the sum is taken one axis at a time over the brood's 2×2×2 values: x, then y, then z.
/// (Issue 20: a fifth of the multiplications of summing each child's 4×4×4 window, and one
/// write per coarse function instead of one per child and function.)
pub(crate) fn push_brood(tab: &DepthTables, ip: [i64; 3], vf: &[[f32; 3]; 8]) -> [f64; 125] {
    // Per axis, coarse offset r + 2 and child bit: the value and derivative tables at
    // k = o − 2I = bit − 2r (zero outside the tables' eight offsets).
    let mut m = [[[0.0f64; 2]; 5]; 3];
    let mut dv = [[[0.0f64; 2]; 5]; 3];
    for a in 0..3 {
        for r in 0..5 {
            let ia = ip[a] + r as i64 - 2;
            for bit in 0..2 {
                let k = bit as i64 - 2 * (r as i64 - 2);
                m[a][r][bit] = tab.cvmass.get(ia, k);
                dv[a][r][bit] = tab.cvderiv.get(ia, k);
            }
        }
    }
    tensor_push(&m, &dv, |c, comp| f64::from(vf[c][comp]))
}

/// The sum over a brood's eight children `c` (child bits per axis) of
/// `v(c, 0) D_x M_y M_z + v(c, 1) M_x D_y M_z + v(c, 2) M_x M_y D_z` for each of the 5×5×5
/// functions around their parent, by window index, where `m[a][r][bit]` and `d[a][r][bit]`
/// are the 1-D value and derivative integrals along axis `a` between the function at offset
/// `r − 2` and a child with bit `bit`. Taken one axis at a time: x, then y, then z.
/// ([`push_brood`] with V's three components; the cycles' parent stiffness push with one
/// coefficient for all three, the stiffness being the same sum of three products.)
pub(crate) fn tensor_push(
    m: &[[[f64; 2]; 5]; 3],
    d: &[[[f64; 2]; 5]; 3],
    v: impl Fn(usize, usize) -> f64,
) -> [f64; 125] {
    // Along x: per (bz, by) and window x, the x component through the derivative, y and z
    // through the value.
    let mut ax = [[[0.0f64; 5]; 2]; 2];
    let mut ay = [[[0.0f64; 5]; 2]; 2];
    let mut az = [[[0.0f64; 5]; 2]; 2];
    for bz in 0..2 {
        for by in 0..2 {
            let c = 2 * by + 4 * bz;
            for x in 0..5 {
                let (m0, m1, d0, d1) = (m[0][x][0], m[0][x][1], d[0][x][0], d[0][x][1]);
                ax[bz][by][x] = v(c, 0) * d0 + v(c + 1, 0) * d1;
                ay[bz][by][x] = v(c, 1) * m0 + v(c + 1, 1) * m1;
                az[bz][by][x] = v(c, 2) * m0 + v(c + 1, 2) * m1;
            }
        }
    }
    // Along y: the x and y components together (y's through the derivative), z's apart.
    let mut pxy = [[[0.0f64; 5]; 5]; 2];
    let mut pz = [[[0.0f64; 5]; 5]; 2];
    for bz in 0..2 {
        for y in 0..5 {
            let (m0, m1, d0, d1) = (m[1][y][0], m[1][y][1], d[1][y][0], d[1][y][1]);
            for x in 0..5 {
                pxy[bz][y][x] = (ax[bz][0][x] * m0 + ax[bz][1][x] * m1)
                    + (ay[bz][0][x] * d0 + ay[bz][1][x] * d1);
                pz[bz][y][x] = az[bz][0][x] * m0 + az[bz][1][x] * m1;
            }
        }
    }
    // Along z: z's component through the derivative.
    let mut out = [0.0f64; 125];
    for z in 0..5 {
        let (m0, m1, d0, d1) = (m[2][z][0], m[2][z][1], d[2][z][0], d[2][z][1]);
        for y in 0..5 {
            for x in 0..5 {
                out[x + 5 * y + 25 * z] =
                    (pxy[0][y][x] * m0 + pxy[1][y][x] * m1) + (pz[0][y][x] * d0 + pz[1][y][x] * d1);
            }
        }
    }
    out
}

/// `Σ_j c_ij y_j` over the children `j` (at the next level) of function `i` (node `n`).
#[allow(clippy::too_many_arguments)]
#[inline]
pub(crate) fn restrict_one(
    _tree: &Octree,
    level: &crate::octree::Level,
    next: &crate::octree::Level,
    basis: Basis,
    d: u32,
    n: u32,
    i: [i64; 3],
    y: &[f64],
) -> f64 {
    let mut s = 0.0;
    if !level.row_has_children(n >> 3) {
        return s; // no child reached: the sum is empty
    }
    let mut ch = [[(0i64, 0.0f64); 4]; 3];
    let mut cnt = [0usize; 3];
    for a in 0..3 {
        cnt[a] = basis.children(d, i[a], &mut ch[a]);
    }
    let row = level.brood_row(n >> 3);
    for cz in &ch[2][..cnt[2]] {
        for cy in &ch[1][..cnt[1]] {
            for cx in &ch[0][..cnt[0]] {
                let j = [cx.0, cy.0, cz.0];
                let o = [(j[0] >> 1) - i[0], (j[1] >> 1) - i[1], (j[2] >> 1) - i[2]];
                let m = neighbor_in_row(&row, n, window_index(o));
                if m == NONE {
                    continue;
                }
                let b = level.child(m);
                if b == NONE {
                    continue;
                }
                let bits = (j[0] & 1) | ((j[1] & 1) << 1) | ((j[2] & 1) << 2);
                let f = b * 8 + bits as u32;
                let _ = next;
                s += cx.1 * cy.1 * cz.1 * y[f as usize];
            }
        }
    }
    s
}

/// Where a prolongation runs: level `t` of `tree`, with the two-scale `weights`, for the
/// functions in `range`.
#[derive(Clone, Copy)]
pub struct Prolongation<'a> {
    /// The tree.
    pub tree: &'a Octree,
    /// The finer level, prolonged to.
    pub t: u32,
    /// The two-scale weights.
    pub weights: &'a Prolong,
    /// The functions that have coefficients.
    pub range: Range,
}

/// Prolongs per-node coefficients `coarse` of level `t − 1` to level `t` (pull form),
/// for functions in `range`; `add` (same level) is added on top, and `store` converts each
/// sum (computed in double precision) to the stored type.
pub fn prolong<const K: usize, T: Send>(
    at: Prolongation,
    coarse: impl Fn(u32) -> [f64; K] + Sync,
    add: impl Fn(usize) -> [f64; K] + Sync,
    store: impl Fn([f64; K]) -> T + Sync,
) -> Vec<T> {
    (0..at.tree.levels[at.t as usize].len() as u32)
        .into_par_iter()
        .map(|n| store(prolong_one(at, &coarse, n, || add(n as usize))))
        .collect()
}

/// [`prolong`] of one coefficient on the broods `keep` accepts, zero on the others. The
/// zeros are a fresh zeroed allocation that is never written, so that where `keep` accepts
/// few broods the pages that hold only zeros are never made resident.
pub fn prolong_broods(
    at: Prolongation,
    coarse: impl Fn(u32) -> f64 + Sync,
    add: impl Fn(usize) -> f64 + Sync,
    keep: impl Fn(u32) -> bool + Sync,
) -> Vec<f64> {
    let mut out = vec![0.0f64; at.tree.levels[at.t as usize].len()];
    out.par_chunks_mut(8)
        .enumerate()
        .filter(|&(b, _)| keep(b as u32))
        .for_each(|(b, nodes)| {
            for (k, o) in nodes.iter_mut().enumerate() {
                let n = 8 * b as u32 + k as u32;
                *o = prolong_one(at, &|q| [coarse(q)], n, || [add(n as usize)])[0];
            }
        });
    out
}

/// [`prolong`] with `add` read from and the result written to `out`, in place (one entry
/// per node of level `t`): the same sums, without a second array of the level alive.
pub fn prolong_in_place<const K: usize, T: Send>(
    at: Prolongation,
    coarse: impl Fn(u32) -> [f64; K] + Sync,
    out: &mut [T],
    add: impl Fn(&T) -> [f64; K] + Sync,
    store: impl Fn([f64; K]) -> T + Sync,
) {
    debug_assert_eq!(out.len(), at.tree.levels[at.t as usize].len());
    out.par_iter_mut().enumerate().for_each(|(n, o)| {
        *o = store(prolong_one(at, &coarse, n as u32, || add(o)));
    });
}

/// Node `n`'s prolonged sum: `add()` plus the coarse coefficients of its parent window,
/// weighted; zero outside `range`.
#[inline]
fn prolong_one<const K: usize>(
    at: Prolongation,
    coarse: &impl Fn(u32) -> [f64; K],
    n: u32,
    add: impl FnOnce() -> [f64; K],
) -> [f64; K] {
    let Prolongation {
        tree,
        t,
        weights,
        range,
    } = at;
    let d = t - DEPTH_OFFSET;
    let level = &tree.levels[t as usize];
    let parent_level = &tree.levels[t as usize - 1];
    let j = func_index(level.key(n), d);
    if !range.contains(j) {
        return [0.0; K];
    }
    let mut acc = add();
    let p = level.brood_parent[(n >> 3) as usize];
    let row = parent_level.brood_row(p >> 3);
    for oz in -1..=1i64 {
        let wz = weights.get(j[2], oz);
        if wz == 0.0 {
            continue;
        }
        for oy in -1..=1i64 {
            let wy = weights.get(j[1], oy);
            if wy == 0.0 {
                continue;
            }
            for ox in -1..=1i64 {
                let wx = weights.get(j[0], ox);
                if wx == 0.0 {
                    continue;
                }
                let q = neighbor_in_row(&row, p, window_index([ox, oy, oz]));
                if q == NONE {
                    continue;
                }
                let w = wx * wy * wz;
                let c = coarse(q);
                for k in 0..K {
                    acc[k] += w * c[k];
                }
            }
        }
    }
    acc
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bspline::{Boundary, Degree};

    const BASES: [(u8, Boundary); 6] = [
        (1, Boundary::Neumann),
        (1, Boundary::Dirichlet),
        (1, Boundary::Free),
        (2, Boundary::Neumann),
        (2, Boundary::Dirichlet),
        (2, Boundary::Free),
    ];

    fn as_degree(d: u8) -> Degree {
        Degree::from_number(d).unwrap()
    }

    #[test]
    fn the_lanes_give_the_same_bits_in_every_vector_width() {
        // Products and sums of awkward magnitudes, where a fused multiply-add or another
        // order would round differently.
        let mut seed = 0x9e37_79b9_7f4a_7c15u64;
        let mut next = || {
            seed ^= seed << 13;
            seed ^= seed >> 7;
            seed ^= seed << 17;
            (seed >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let terms: Vec<([f64; 8], [f64; 8])> = (0..1000)
            .map(|_| {
                let c = std::array::from_fn(|_| next() * 1e3);
                (c, std::array::from_fn(|_| next() / 3.0))
            })
            .collect();
        let mut by_hand = [0.0f64; 8];
        for (c, v) in &terms {
            for l in 0..8 {
                let p = c[l] * v[l];
                by_hand[l] += p;
            }
        }
        let sum = |f: fn(&mut [f64; 8], &[f64; 8], &[f64; 8])| {
            let mut acc = [0.0f64; 8];
            terms.iter().for_each(|(c, v)| f(&mut acc, c, v));
            acc.map(f64::to_bits)
        };
        assert_eq!(sum(PlainLanes::multiply_add), by_hand.map(f64::to_bits));
        #[cfg(target_arch = "x86_64")]
        if std::arch::is_x86_feature_detected!("avx") {
            assert_eq!(sum(AvxLanes::multiply_add), by_hand.map(f64::to_bits));
        }
    }

    #[test]
    fn stiffness_stencils_are_symmetric_and_annihilate_constants() {
        for (d_num, boundary) in BASES {
            let degree = d_num;
            let fem = Basis::new(as_degree(d_num), boundary);
            let vb = Basis::new(Degree::Quadratic, boundary.derivative());
            for d in [2u32, 3, 5] {
                let tab = DepthTables::new(fem, vb, d);
                let r = i64::from(degree);
                let (lo, hi) = (tab.range.lo, tab.range.hi);
                // Rows near the corner, the faces and the middle.
                let probes: Vec<i64> = vec![lo, lo + 1, lo + 2, (lo + hi) / 2, hi - 1, hi];
                for &x in &probes {
                    for &y in &probes {
                        for &z in &probes {
                            let i = [x, y, z];
                            if !tab.range.contains(i) {
                                continue;
                            }
                            let mut row_sum = 0.0;
                            for oz in -r..=r {
                                for oy in -r..=r {
                                    for ox in -r..=r {
                                        let o = [ox, oy, oz];
                                        let j = [x + ox, y + oy, z + oz];
                                        let a = tab.stiffness(i, o);
                                        if tab.range.contains(j) {
                                            let b = tab.stiffness(j, [-ox, -oy, -oz]);
                                            assert!((a - b).abs() <= 1e-12 * a.abs().max(1.0), "{degree} {boundary:?} d{d} {i:?} {o:?}: {a} vs {b}");
                                            row_sum += a;
                                        } else {
                                            assert_eq!(a, 0.0);
                                        }
                                        if tab.range.interior(i, 3) {
                                            assert!(
                                                (a - tab.stencil[window_index(o)]).abs()
                                                    < 1e-12 * a.abs().max(1.0)
                                            );
                                        }
                                    }
                                }
                            }
                            assert!(tab.stiffness(i, [0, 0, 0]) > 0.0);
                            if boundary != Boundary::Dirichlet {
                                assert!(
                                    row_sum.abs() < 1e-10,
                                    "{degree} {boundary:?} row {i:?} sums to {row_sum}"
                                );
                            }
                        }
                    }
                }
            }
        }
    }

    /// A reproducible value in [−1, 1) from a counter (xorshift).
    fn noise(state: &mut u64) -> f32 {
        *state ^= *state << 13;
        *state ^= *state >> 7;
        *state ^= *state << 17;
        ((*state >> 40) as f32 / (1u64 << 24) as f32) * 2.0 - 1.0
    }

    /// Function indices of a brood's first node to probe: against each end, and the middle.
    fn brood_probes(tab: &DepthTables) -> Vec<i64> {
        let (lo, hi) = (tab.range.lo, tab.range.hi);
        let even = |i: i64| i - i.rem_euclid(2);
        let mut p = vec![
            even(lo),
            even(lo) + 2,
            even((lo + hi) / 2),
            even(hi) - 2,
            even(hi),
        ];
        p.dedup();
        p
    }

    #[test]
    fn the_brood_v_term_taken_one_axis_at_a_time_is_the_windows_sum() {
        let mut state = 0x9e37_79b9_7f4a_7c15u64;
        for (d_num, boundary) in BASES {
            let fem = Basis::new(as_degree(d_num), boundary);
            let vb = Basis::new(Degree::Quadratic, boundary.derivative());
            let tab = DepthTables::new(fem, vb, 4);
            // 27 broods of V around the brood, two of them absent.
            let v: Vec<[f32; 3]> = (0..27 * 8)
                .map(|_| std::array::from_fn(|_| noise(&mut state)))
                .collect();
            let mut nbrs: BroodRow = std::array::from_fn(|s| s as u32);
            nbrs[4] = NONE;
            nbrs[22] = NONE;
            let probes = brood_probes(&tab);
            for (&x, (&y, &z)) in probes.iter().zip(probes.iter().rev().zip(&probes)) {
                let i0 = [x, y, z];
                let got = v_brood_term(&tab, i0, &nbrs, &v);
                for (k, &got) in got.iter().enumerate() {
                    let bits: [i64; 3] = std::array::from_fn(|a| ((k >> a) & 1) as i64);
                    let i: [i64; 3] = std::array::from_fn(|a| i0[a] + bits[a]);
                    let mut want = 0.0;
                    let mut scale = 0.0;
                    for w in 0..125 {
                        let o = [w % 5 - 2, w / 5 % 5 - 2, w / 25 - 2];
                        // The neighbour's brood slot and child bits (local coordinate
                        // 2 + bit + o in the 6×6×6 nodes of the 27 broods).
                        let l: [i64; 3] = std::array::from_fn(|a| 2 + bits[a] + o[a]);
                        let slot = (l[0] / 2 + 3 * (l[1] / 2) + 9 * (l[2] / 2)) as usize;
                        if nbrs[slot] == NONE {
                            continue;
                        }
                        let node = 8 * slot + (l[0] % 2 + 2 * (l[1] % 2) + 4 * (l[2] % 2)) as usize;
                        let vm = v[node].map(f64::from);
                        let m: [f64; 3] = std::array::from_fn(|a| tab.vmass.get(i[a], o[a]));
                        let dv: [f64; 3] = std::array::from_fn(|a| tab.vderiv.get(i[a], o[a]));
                        let terms = [
                            vm[0] * dv[0] * m[1] * m[2],
                            vm[1] * m[0] * dv[1] * m[2],
                            vm[2] * m[0] * m[1] * dv[2],
                        ];
                        want += terms.iter().sum::<f64>();
                        scale += terms.iter().map(|t| t.abs()).sum::<f64>();
                    }
                    assert!(
                        (got - want).abs() <= 1e-13 * scale,
                        "{d_num} {boundary:?} {i:?}: {got} vs {want}"
                    );
                }
            }
        }
    }

    #[test]
    fn the_restriction_is_zero_outside_the_reach_of_a_sparse_finer_g() {
        let tree = Octree::full_depth_4_and_one_path_to_6();
        let mut state = 0x5851_f42d_4c95_7f2du64;
        for (d_num, boundary) in BASES {
            let fem = Basis::new(as_degree(d_num), boundary);
            let t = 4 + DEPTH_OFFSET;
            let (level, next) = (&tree.levels[t as usize], &tree.levels[t as usize + 1]);
            // G of the next level: nonzero on its first brood only, the rest zeros of both
            // signs.
            let g: Vec<f64> = (0..next.len())
                .map(|f| match f {
                    0..8 => f64::from(noise(&mut state)) + 2.0,
                    _ if f % 2 == 0 => -0.0,
                    _ => 0.0,
                })
                .collect();
            let reach = sparse_reach(level, next, &g).expect("a sparse G has a reach");
            let (mut inside, mut outside) = (0, 0);
            for n in 0..level.len() as u32 {
                let i = func_index(level.key(n), 4);
                let r = restrict_one(&tree, level, next, fem, 4, n, i, &g);
                if reach.contains(n >> 3) {
                    inside += usize::from(r != 0.0);
                } else {
                    assert_eq!(
                        r.to_bits(),
                        0.0f64.to_bits(),
                        "{d_num} {boundary:?} node {n}"
                    );
                    outside += 1;
                }
            }
            assert!(
                inside > 0 && outside > 0,
                "{d_num} {boundary:?}: {inside} {outside}"
            );
            // A G that is nonzero almost everywhere has no reach worth finding.
            let dense: Vec<f64> = (0..next.len()).map(|f| 1.0 + f as f64).collect();
            assert!(sparse_reach(level, next, &dense).is_none());
        }
    }

    #[test]
    fn the_brood_push_taken_one_axis_at_a_time_is_the_childrens_windows() {
        let mut state = 0x2545_f491_4f6c_dd1du64;
        for (d_num, boundary) in BASES {
            let fem = Basis::new(as_degree(d_num), boundary);
            let vb = Basis::new(Degree::Quadratic, boundary.derivative());
            let tab = DepthTables::new(fem, vb, 4);
            let vf: [[f32; 3]; 8] =
                std::array::from_fn(|_| std::array::from_fn(|_| noise(&mut state)));
            // Parents' indices against each end and in the middle.
            let (lo, hi) = (tab.range.lo, tab.range.hi - 1);
            for ip in [[lo, hi, lo + 1], [(lo + hi) / 2; 3], [hi, lo, hi - 1]] {
                let got = push_brood(&tab, ip, &vf);
                let mut want = [0.0f64; 125];
                let mut scale = [0.0f64; 125];
                for (c, vc) in vf.iter().enumerate() {
                    let vc = vc.map(f64::from);
                    for w in 0..125 {
                        let r = [w % 5 - 2, w / 5 % 5 - 2, w / 25 - 2];
                        let (mut m, mut dv) = ([0.0; 3], [0.0; 3]);
                        for a in 0..3 {
                            let (ia, o) = (ip[a] + r[a], 2 * ip[a] + ((c >> a) & 1) as i64);
                            m[a] = tab.cvmass.get(ia, o - 2 * ia);
                            dv[a] = tab.cvderiv.get(ia, o - 2 * ia);
                        }
                        let terms = [
                            vc[0] * dv[0] * m[1] * m[2],
                            vc[1] * m[0] * dv[1] * m[2],
                            vc[2] * m[0] * m[1] * dv[2],
                        ];
                        want[w as usize] += terms.iter().sum::<f64>();
                        scale[w as usize] += terms.iter().map(|t| t.abs()).sum::<f64>();
                    }
                }
                for w in 0..125 {
                    assert!(
                        (got[w] - want[w]).abs() <= 1e-13 * scale[w],
                        "{d_num} {boundary:?} parent {ip:?} window {w}: {} vs {}",
                        got[w],
                        want[w]
                    );
                }
                // Most of the window is reached, near the ends too.
                assert!(scale.iter().filter(|&&s| s > 0.0).count() >= 18);
            }
        }
    }

    #[test]
    fn prolongation_weights_reproduce_the_two_scale_relation() {
        for (d_num, boundary) in BASES {
            let degree = d_num;
            let basis = Basis::new(as_degree(d_num), boundary);
            for d in 1..6u32 {
                let p = Prolong::new(basis, d);
                let (lo, hi) = basis.index_range(d);
                // Prolonging the coefficients of one coarse function gives its children weights.
                let (clo, chi) = basis.index_range(d - 1);
                let mut out = [(0i64, 0.0); 4];
                for c in clo..=chi {
                    let k = basis.children(d - 1, c, &mut out);
                    for j in lo..=hi {
                        let o = c - (j >> 1);
                        let w = if (-1..=1).contains(&o) {
                            p.get(j, o)
                        } else {
                            0.0
                        };
                        let expect: f64 = out[..k].iter().filter(|e| e.0 == j).map(|e| e.1).sum();
                        assert!(
                            (w - expect).abs() < 1e-15,
                            "{degree} {boundary:?} d{d} c{c} j{j}"
                        );
                    }
                }
            }
        }
    }
}
