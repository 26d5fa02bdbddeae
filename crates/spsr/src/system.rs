//! The linear system of each depth (ALGORITHM.md §5.5, §6): 1-D integral tables, the vector
//! field V splatted into the tree (§3.6), the screening clusters (§3.7), the divergence
//! constraints `∫∇B_i·V` gathered across depths, and the prolongation/restriction operators.
//!
//! Conventions: "level" `t` is a tree depth, "depth" `d = t − DEPTH_OFFSET` is the unit-cube
//! depth. A node's function index along an axis is its unit offset (`key − 2^d`).

use rayon::prelude::*;

use crate::shared_slice::split_into;

use crate::bspline::{table, Basis, Integrand, Table1D};
use crate::octree::{
    brood_offset, func_index, neighbor_in_row, window_index, BroodRow, Level, NodeRank, Octree,
    DEPTH_OFFSET, NONE,
};
use crate::shared_slice::SharedSlice;

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
    /// Interior stencils of `∫∂_a B_i · B^V_j` for each component `a`, by window index.
    pub vstencil: [[f64; 125]; 3],
    /// Interior parent stiffness stencils, by child parity (x bit 0) and parent window index.
    pub pstencil: Box<[[f64; 125]; 8]>,
    /// Interior parent V stencils, by child parity, component and parent window index.
    pub pvstencil: Box<[[[f64; 125]; 3]; 8]>,
    /// By child parity, the parent window indices where `pstencil` or `pvstencil` is nonzero.
    pub pnonzero: [Vec<u8>; 8],
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
        let mut vstencil = [[0.0; 125]; 3];
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
            let v = vector(&vmass, &vderiv, [mid; 3]);
            for a in 0..3 {
                vstencil[a][w] = v[a];
            }
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
        Self {
            pnonzero,
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
            vstencil,
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

#[inline]
fn stiffness_3d(mass: &Table1D, stiff: &Table1D, i: [i64; 3], o: [i64; 3]) -> f64 {
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
    /// broods; the lanes are added pairwise in a fixed order.
    #[inline]
    pub fn row(&self, nbrs: &BroodRow, n: u32, brood: impl Fn(u32) -> [[f64; 8]; K]) -> f64 {
        let mut acc = [0.0f64; 8];
        for (slot, coef) in &self.rows[(n & 7) as usize] {
            let b = nbrs[usize::from(*slot)];
            if b == NONE {
                continue;
            }
            let v = brood(b);
            for (ck, vk) in coef.iter().zip(&v) {
                for l in 0..8 {
                    acc[l] += ck[l] * vk[l];
                }
            }
        }
        ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]))
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
    let pushed = match next {
        Some(next) if !v_finer.is_empty() => push_finer_v(level, next, d, tab, v_finer),
        _ => Vec::new(),
    };
    // An empty `G_{t+1}` is the zero one (see the end).
    let g_finer = g_finer.filter(|g| !g.is_empty());
    let vbrood = BroodStencil::new([&tab.vstencil[0], &tab.vstencil[1], &tab.vstencil[2]]);
    let with_v = broods_with_v(v);
    // `near_v`: whether a brood around `n`'s has a nonzero V; where none has, the stencil's
    // sum is +0 (each lane starts at +0 and adds only zero products), which is added as such.
    let row = |n: u32, nbrs: &BroodRow, near_v: bool| {
        let i = func_index(level.key(n), d);
        if !tab.range.contains(i) {
            return (0.0, 0.0);
        }
        let interior = tab.is_interior(i);
        let mut g = pushed.get(n as usize).copied().unwrap_or(0.0);
        if let (Some(gf), Some(next)) = (g_finer, next) {
            g += restrict_one(tree, level, next, fem, d, n, i, gf);
        }
        let mut b = g;
        if !v.is_empty() && interior {
            b += if near_v {
                vbrood.row(nbrs, n, |m| v_brood(v, m))
            } else {
                0.0
            };
        } else if !v.is_empty() {
            for w in 0..125 {
                let m = neighbor_in_row(nbrs, n, w);
                if m == NONE {
                    continue;
                }
                let vm = v[m as usize];
                if vm == [0.0; 3] {
                    continue;
                }
                let vm = [f64::from(vm[0]), f64::from(vm[1]), f64::from(vm[2])];
                let o = [
                    (w % 5) as i64 - 2,
                    ((w / 5) % 5) as i64 - 2,
                    (w / 25) as i64 - 2,
                ];
                let mx = tab.vmass.get(i[0], o[0]);
                let my = tab.vmass.get(i[1], o[1]);
                let mz = tab.vmass.get(i[2], o[2]);
                let dx = tab.vderiv.get(i[0], o[0]);
                let dy = tab.vderiv.get(i[1], o[1]);
                let dz = tab.vderiv.get(i[2], o[2]);
                b += vm[0] * dx * my * mz + vm[1] * mx * dy * mz + vm[2] * mx * my * dz;
            }
        }
        (g, b as f32)
    };
    let near_v = |nbrs: &BroodRow| any_with_v(nbrs, &with_v);
    let mut t_out = vec![0.0f32; level.len()];
    if pushed.is_empty() && g_finer.is_none() {
        // No finer V: `G_t` is zero, and is not stored (at the finest level it would be the
        // largest array alive while the constraints are made).
        t_out.par_chunks_mut(8).enumerate().for_each(|(b, t)| {
            let nbrs = level.brood_row(b as u32);
            let near = near_v(&nbrs);
            for (k, t) in t.iter_mut().enumerate() {
                *t = row(8 * b as u32 + k as u32, &nbrs, near).1;
            }
        });
        (Vec::new(), t_out)
    } else {
        let mut g_out = vec![0.0f64; level.len()];
        (g_out.par_chunks_mut(8).zip(t_out.par_chunks_mut(8)))
            .enumerate()
            .for_each(|(b, (g, t))| {
                let nbrs = level.brood_row(b as u32);
                let near = near_v(&nbrs);
                for (k, (g, t)) in g.iter_mut().zip(t).enumerate() {
                    (*g, *t) = row(8 * b as u32 + k as u32, &nbrs, near);
                }
            });
        (g_out, t_out)
    }
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

/// The V of brood `b`'s eight nodes, component by component.
#[inline]
fn v_brood(v: &[[f32; 3]], b: u32) -> [[f64; 8]; 3] {
    let nodes: &[[f32; 3]; 8] = v[8 * b as usize..8 * b as usize + 8]
        .try_into()
        .expect("eight nodes");
    std::array::from_fn(|a| std::array::from_fn(|k| f64::from(nodes[k][a])))
}

/// The broods of `next` with a nonzero V, in 125 colours by their parent's key modulo 5 per
/// axis (see [`push_finer_v`]), each colour in brood order. Runs of broods are sorted into
/// colours in parallel, and each colour's runs joined in order.
pub(crate) fn push_colours(level: &Level, next: &Level, v_finer: &[[f32; 3]]) -> Vec<Vec<u32>> {
    const RUN: u32 = 1 << 14;
    let broods = (next.len() / 8) as u32;
    let runs: Vec<Vec<Vec<u32>>> = (0..broods.div_ceil(RUN))
        .into_par_iter()
        .map(|r| {
            let mut colours: Vec<Vec<u32>> = vec![Vec::new(); 125];
            for b in r * RUN..broods.min((r + 1) * RUN) {
                let base = (b * 8) as usize;
                if v_finer[base..base + 8].iter().all(|x| *x == [0.0; 3]) {
                    continue;
                }
                let k = level.key(next.brood_parent[b as usize]);
                colours[(k[0] % 5 + 5 * (k[1] % 5) + 25 * (k[2] % 5)) as usize].push(b);
            }
            colours
        })
        .collect();
    (0..125)
        .map(|c| runs.iter().flat_map(|run| &run[c]).copied().collect())
        .collect()
}

/// `∫∇B_I · V_{d+1}` for every FEM function `I` of level `t` (depth `d`), pushed from each
/// nonzero V coefficient of the next level to the 4×4×4 coarse functions it overlaps (all in
/// its parent's 5×5×5 window). Broods are coloured by their parent's key modulo 5 per axis:
/// parents of one colour are at least 5 apart, so their windows never overlap and a colour is
/// pushed in parallel without races, in an order that does not depend on the thread count.
fn push_finer_v(
    level: &Level,
    next: &Level,
    d: u32,
    tab: &DepthTables,
    v_finer: &[[f32; 3]],
) -> Vec<f64> {
    let mut g = vec![0.0f64; level.len()];
    let colours = push_colours(level, next, v_finer);
    let gs = SharedSlice::new(&mut g);
    for list in &colours {
        list.par_iter().with_min_len(64).for_each(|&b| {
            let p = next.brood_parent[b as usize];
            let ip = func_index(level.key(p), d);
            let row = level.brood_row(p >> 3);
            for c in 0..8u32 {
                let vf = v_finer[(b * 8 + c) as usize];
                if vf == [0.0; 3] {
                    continue;
                }
                let vf = vf.map(f64::from);
                // Per axis: the 4 coarse indices I overlapping fine index o = 2·ip + bit, their
                // window offsets I − ip, and the 1-D tables at k = o − 2I.
                let mut rel = [[0i64; 4]; 3];
                let mut m = [[0.0f64; 4]; 3];
                let mut dv = [[0.0f64; 4]; 3];
                for a in 0..3 {
                    let bit = i64::from((c >> a) & 1);
                    let o = 2 * ip[a] + bit;
                    for (s, r) in (bit - 2..=bit + 1).enumerate() {
                        let ia = ip[a] + r;
                        rel[a][s] = r;
                        m[a][s] = tab.cvmass.get(ia, o - 2 * ia);
                        dv[a][s] = tab.cvderiv.get(ia, o - 2 * ia);
                    }
                }
                for z in 0..4 {
                    for y in 0..4 {
                        let (mz, dz, my, dy) = (m[2][z], dv[2][z], m[1][y], dv[1][y]);
                        if mz == 0.0 && dz == 0.0 || my == 0.0 && dy == 0.0 {
                            continue;
                        }
                        for x in 0..4 {
                            let (mx, dx) = (m[0][x], dv[0][x]);
                            let val =
                                vf[0] * dx * my * mz + vf[1] * mx * dy * mz + vf[2] * mx * my * dz;
                            if val == 0.0 {
                                continue;
                            }
                            let q = neighbor_in_row(
                                &row,
                                p,
                                window_index([rel[0][x], rel[1][y], rel[2][z]]),
                            );
                            if q == NONE {
                                continue;
                            }
                            // SAFETY: within one colour, only this brood's task writes the
                            // window of its parent `p` (see the colouring above).
                            unsafe { gs.set(q as usize, gs.get(q as usize) + val) };
                        }
                    }
                }
            }
        });
    }
    g
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
    let mut ch = [[(0i64, 0.0f64); 4]; 3];
    let mut cnt = [0usize; 3];
    for a in 0..3 {
        cnt[a] = basis.children(d, i[a], &mut ch[a]);
    }
    let mut s = 0.0;
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
