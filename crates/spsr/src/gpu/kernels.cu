// The solver's kernels on the GPU (ALGORITHM.md §7): the Gauss–Seidel relaxation of one
// octree depth (§7.1), χ at the depth's screening clusters, and the depth's right-hand sides
// (§7.2: the constraints, minus what the coarser solution meets, plus the screening targets).
//
// One thread handles one node (or one cluster). Every operation mirrors the CPU's code in
// `solver.rs` and `solver/cycles.rs` in the same order, and the host compiles this file with
// `--fmad=false`, so that each product and sum rounds as on the CPU: the results are the
// CPU's to the last bit. The function named in each comment is the one mirrored.
//
// The relaxation: a launch covers the nodes of one (block colour, node colour) class of
// `Op::gauss_seidel_cpu`; nodes of one node colour share no stiffness entry and no screening
// cluster, so a launch has no races, and launching the classes in the CPU's order reproduces
// the CPU's sweep exactly.
//
// The host prepends `DEGREE`, the window tables `WSLOT` and `WBITS` (octree::WINDOW) and the
// cluster broods `CBROOD_START`, `CBROOD_SLOT` and `CBROOD_MASK` (solver.rs `cluster_broods`).

#define NONE 0xffffffffu
#define TAU 0.5

typedef unsigned int u32;
typedef unsigned long long u64;
typedef long long i64;

// The node `w` (window index of an offset in [-2,2]^3) away from node `n` (octree.rs
// `neighbor_in`), or NONE.
__device__ __forceinline__ u32 neighbour(const u32* __restrict__ nbrs, u32 n, int w) {
    u32 c = n & 7u;
    u32 b = nbrs[(u64)(n >> 3) * 27u + WSLOT[c * 125u + w]];
    return b == NONE ? NONE : b * 8u + WBITS[c * 125u + w];
}

// The function index of node `n` (octree.rs `func_index` of `Level::key`).
__device__ __forceinline__ void func_index(const u32* __restrict__ brood_key, int depth, u32 n,
                                           i64 i[3]) {
    const u32* key = brood_key + (u64)(n >> 3) * 3u;
    i64 half = (i64)1 << depth;
    i[0] = (i64)(2u * key[0] + (n & 1u)) - half;
    i[1] = (i64)(2u * key[1] + ((n >> 1) & 1u)) - half;
    i[2] = (i64)(2u * key[2] + ((n >> 2) & 1u)) - half;
}

// Every index at least `m` from both ends of `lo..=hi` (system.rs `Range::interior`).
__device__ __forceinline__ bool interior(const i64 i[3], i64 lo, i64 hi, i64 m) {
    for (int a = 0; a < 3; a++) {
        if (i[a] - lo < m || hi - i[a] < m) return false;
    }
    return true;
}

__device__ __forceinline__ bool in_range(const i64 i[3], i64 lo, i64 hi) {
    for (int a = 0; a < 3; a++) {
        if (i[a] < lo || i[a] > hi) return false;
    }
    return true;
}

// A 1-D table entry for index `i` and offset `off` (bspline.rs `Table1D::get`): rows
// `lo..=hi`, five offsets each, zero outside.
__device__ __forceinline__ double table(const double* __restrict__ t, i64 lo, i64 hi, i64 i,
                                        i64 off) {
    if (off < -2 || off > 2 || i < lo || i > hi) return 0.0;
    return t[(i - lo) * 5 + off + 2];
}

// `∫∇B_i·∇B_{i+o}` from the 1-D tables (system.rs `stiffness_3d`).
__device__ __forceinline__ double stiffness(const double* __restrict__ mass,
                                            const double* __restrict__ stiff, i64 lo, i64 hi,
                                            const i64 i[3], const i64 o[3]) {
    double m0 = table(mass, lo, hi, i[0], o[0]);
    double m1 = table(mass, lo, hi, i[1], o[1]);
    double m2 = table(mass, lo, hi, i[2], o[2]);
    double k0 = table(stiff, lo, hi, i[0], o[0]);
    double k1 = table(stiff, lo, hi, i[1], o[1]);
    double k2 = table(stiff, lo, hi, i[2], o[2]);
    return k0 * m1 * m2 + m0 * k1 * m2 + m0 * m1 * k2;
}

// The screening clusters of one depth.
struct Clusters {
    const u64* __restrict__ rank_bits;
    const u32* __restrict__ rank_before;
    u64 rank_words;
    const double* __restrict__ omega;
    const int* __restrict__ first;
    const float* __restrict__ vals;
};

// Calls `f(c, B_i(p_c))` for every cluster `c` whose basis value at function `i` (node `n`)
// is not zero, in the CPU's order (solver.rs `Op::for_each_cluster`): the neighbouring broods
// of `CBROOD_SLOT` (the host's `cluster_broods`) in order, and in each brood the members of its
// mask by child position. A brood's eight nodes share one rank word (`NodeRank::brood`).
template <typename F>
__device__ __forceinline__ void for_each_cluster(const u32* __restrict__ nbrs, u32 n,
                                                 const i64 i[3], const Clusters& cl, F f) {
    u32 pos = n & 7u;
    const u32* around = nbrs + (u64)(n >> 3) * 27u;
    for (u32 e = CBROOD_START[pos]; e < CBROOD_START[pos + 1]; e++) {
        u32 b = around[CBROOD_SLOT[e]];
        if (b == NONE) continue;
        u64 k = b >> 3;
        if (k >= cl.rank_words) continue;
        u64 word = cl.rank_bits[k];
        u32 shift = (b & 7u) * 8u;
        u32 members = (u32)((word >> shift) & 0xffu);
        if (members == 0) continue;
        u32 first = cl.rank_before[k] + (u32)__popcll(word & ((1ull << shift) - 1ull));
        u32 bits = members & (u32)CBROOD_MASK[e];
        while (bits != 0) {
            u32 kk = (u32)(__ffs(bits) - 1);
            u32 c = first + (u32)__popc(members & ((1u << kk) - 1u));
            // B_i(p_c) (system.rs `Clusters::basis_value`).
            double bv = 1.0;
            for (int a = 0; a < 3; a++) {
                i64 off = i[a] - (i64)cl.first[(u64)c * 3u + a];
                if (off < 0 || off > DEGREE) {
                    bv = 0.0;
                    break;
                }
                bv *= (double)cl.vals[(u64)c * 9u + a * 3 + off];
            }
            if (bv != 0.0) f(c, bv);
            bits &= bits - 1u;
        }
    }
}

extern "C" __global__ void relax(
    // The nodes of this launch: list[first .. first + count].
    const u32* __restrict__ list, u64 first, u32 count,
    // The level: 27 neighbouring broods and the key of each brood's parent.
    const u32* __restrict__ nbrs, const u32* __restrict__ brood_key, int depth,
    // Function index range, the interior stiffness stencil (125 entries) and the same by
    // neighbouring brood: per child position entries brood_start[c]..brood_start[c + 1], each a
    // brood slot and eight coefficients.
    i64 lo, i64 hi, const double* __restrict__ stencil, const u32* __restrict__ brood_start,
    const u32* __restrict__ brood_slot, const double* __restrict__ brood_coef,
    // Same-depth 1-D mass and stiffness tables, rows lo..=hi.
    const double* __restrict__ mass, const double* __restrict__ stiff,
    // Clusters: the node rank bitmap, ω, first function index and basis values per axis.
    const u64* __restrict__ rank_bits, const u32* __restrict__ rank_before, u64 rank_words,
    const double* __restrict__ omega, const int* __restrict__ cfirst,
    const float* __restrict__ cvals,
    // Right-hand side (per node), coefficients (per node), χ at the clusters.
    const float* __restrict__ rhs, float* x, double* chi) {
    u32 t = blockIdx.x * blockDim.x + threadIdx.x;
    if (t >= count) return;
    u32 n = list[first + t];
    i64 i[3];
    func_index(brood_key, depth, n, i);
    // Op::relax
    if (!in_range(i, lo, hi)) return;
    bool inner = interior(i, lo, hi, 3);
    // Σ_j L_ij x_j over the same-depth window (Op::stiffness_row).
    double s = 0.0;
    if (inner) {
        // By neighbouring brood, eight lanes summed pairwise (system.rs `BroodStencil::row`).
        // A zero coefficient adds a zero, which changes no lane: it is skipped, and with it
        // the nodes outside the window, which other threads of the launch may be writing.
        const u32* around = nbrs + (u64)(n >> 3) * 27u;
        double acc[8] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
        u32 pos = n & 7u;
        for (u32 e = brood_start[pos]; e < brood_start[pos + 1]; e++) {
            u32 b = around[brood_slot[e]];
            if (b == NONE) continue;
            for (int l = 0; l < 8; l++) {
                double cf = brood_coef[(u64)e * 8u + l];
                if (cf != 0.0) acc[l] += cf * (double)x[(u64)b * 8u + l];
            }
        }
        s = ((acc[0] + acc[1]) + (acc[2] + acc[3])) + ((acc[4] + acc[5]) + (acc[6] + acc[7]));
    } else {
        for (i64 z = -DEGREE; z <= DEGREE; z++) {
            for (i64 y = -DEGREE; y <= DEGREE; y++) {
                for (i64 xx = -DEGREE; xx <= DEGREE; xx++) {
                    int w = (int)((xx + 2) + 5 * (y + 2) + 25 * (z + 2));
                    u32 m = neighbour(nbrs, n, w);
                    if (m == NONE) continue;
                    double xm = (double)x[m];
                    if (xm != 0.0) {
                        i64 o[3] = {xx, y, z};
                        s += stiffness(mass, stiff, lo, hi, i, o) * xm;
                    }
                }
            }
        }
    }
    double dg;
    if (inner) {
        dg = stencil[62];
    } else {
        i64 o[3] = {0, 0, 0};
        dg = stiffness(mass, stiff, lo, hi, i, o);
    }
    Clusters cl = {rank_bits, rank_before, rank_words, omega, cfirst, cvals};
    u32 touched_c[27];
    double touched_b[27];
    int k = 0;
    for_each_cluster(nbrs, n, i, cl, [&](u32 c, double bv) {
        double wc = omega[c] * bv;
        s += wc * chi[c];
        dg += wc * bv;
        touched_c[k] = c;
        touched_b[k] = bv;
        k++;
    });
    double dx = ((double)rhs[n] - s) / dg;
    x[n] = (float)((double)x[n] + dx);
    for (int j = 0; j < k; j++) {
        chi[touched_c[j]] = chi[touched_c[j]] + dx * touched_b[j];
    }
}

// χ_d at every cluster from the level's coefficients `x` (solver.rs `cluster_value`).
extern "C" __global__ void cluster_values(
    u32 count, const u32* __restrict__ cl_node, const int* __restrict__ cfirst,
    const float* __restrict__ cvals, const u32* __restrict__ nbrs,
    const u32* __restrict__ brood_key, int depth, const float* __restrict__ x,
    double* __restrict__ chi) {
    u32 c = blockIdx.x * blockDim.x + threadIdx.x;
    if (c >= count) return;
    u32 node = cl_node[c];
    i64 own[3];
    func_index(brood_key, depth, node, own);
    const int* f = cfirst + (u64)c * 3u;
    const float* v = cvals + (u64)c * 9u;
    double s = 0.0;
    for (int z = 0; z <= DEGREE; z++) {
        for (int y = 0; y <= DEGREE; y++) {
            for (int xx = 0; xx <= DEGREE; xx++) {
                i64 d0 = (i64)f[0] + xx - own[0];
                i64 d1 = (i64)f[1] + y - own[1];
                i64 d2 = (i64)f[2] + z - own[2];
                int w = (int)((d0 + 2) + 5 * (d1 + 2) + 25 * (d2 + 2));
                u32 m = neighbour(nbrs, node, w);
                if (m == NONE) continue;
                s += (double)v[0 * 3 + xx] * (double)v[1 * 3 + y] * (double)v[2 * 3 + z] *
                     (double)x[m];
            }
        }
    }
    chi[c] = s;
}

// The parent depth as the coupling with the coarser levels reads it.
struct Parent {
    // Parent node of each brood of the level.
    const u32* __restrict__ brood_parent;
    // The parent level's 27 neighbouring broods.
    const u32* __restrict__ nbrs;
    // Interior parent stencils by child parity: stiffness [8][125], V [8][3][125].
    const double* __restrict__ pstencil;
    const double* __restrict__ pvstencil;
    // By child parity, the window indices where they are nonzero: nonzero[start[c]..start[c+1]].
    const u32* __restrict__ nonzero_start;
    const u32* __restrict__ nonzero;
    // 1-D tables against the parent's functions, rows lo..=hi, five offsets each.
    const double* __restrict__ pmass;
    const double* __restrict__ pstiff;
    const double* __restrict__ pvmass;
    const double* __restrict__ pvderiv;
};

// The coupling of function `i` (node `n`) with the coarser levels, into s[0] (and with `fix`,
// the coarser V's term also into s[1]): `− Σ_q A_iq pc_q + ∫∇B_i·V_q` over the parent window
// (solver.rs `Op::coarse_coupling`, with its interior and boundary halves). `sol` and `vec`
// choose the terms; `vc` holds three floats per parent node.
__device__ __forceinline__ void coarse_coupling(double s[2], bool sol, bool vec, bool fix, u32 n,
                                                const i64 i[3], i64 lo, i64 hi,
                                                const Parent& p, const double* __restrict__ pc,
                                                const float* __restrict__ vc) {
    u32 par = p.brood_parent[n >> 3];
    if (interior(i, lo, hi, 4)) {
        // Op::add_interior_coupling
        u32 c = (u32)((i[0] & 1) | ((i[1] & 1) << 1) | ((i[2] & 1) << 2));
        const double* ps = p.pstencil + c * 125u;
        const double* pv = p.pvstencil + c * 375u;
        for (u32 k = p.nonzero_start[c]; k < p.nonzero_start[c + 1]; k++) {
            int w = (int)p.nonzero[k];
            // Without the V term, the CPU walks only the entries of nonzero stiffness
            // (system.rs `DepthTables::psnonzero`, the same order).
            if (!vec && ps[w] == 0.0) continue;
            u32 q = neighbour(p.nbrs, par, w);
            if (q == NONE) continue;
            if (sol) s[0] -= ps[w] * pc[q];
            if (vec) {
                const float* v = vc + (u64)q * 3u;
                double term = (double)v[0] * pv[w] + (double)v[1] * pv[125 + w] +
                              (double)v[2] * pv[250 + w];
                s[0] += term;
                if (fix) s[1] += term;
            }
        }
        return;
    }
    // Op::add_boundary_coupling
    double pm[3][5], pk[3][5], vm[3][5], vd[3][5];
    for (int a = 0; a < 3; a++) {
        for (int o = 0; o < 5; o++) {
            pm[a][o] = table(p.pmass, lo, hi, i[a], o - 2);
            pk[a][o] = table(p.pstiff, lo, hi, i[a], o - 2);
            vm[a][o] = table(p.pvmass, lo, hi, i[a], o - 2);
            vd[a][o] = table(p.pvderiv, lo, hi, i[a], o - 2);
        }
    }
    for (int w = 0; w < 125; w++) {
        int ox = w % 5, oy = (w / 5) % 5, oz = w / 25;
        u32 q = neighbour(p.nbrs, par, w);
        if (q == NONE) continue;
        double xq = sol ? pc[q] : 0.0;
        if (xq != 0.0) {
            double k = pk[0][ox] * pm[1][oy] * pm[2][oz] + pm[0][ox] * pk[1][oy] * pm[2][oz] +
                       pm[0][ox] * pm[1][oy] * pk[2][oz];
            s[0] -= k * xq;
        }
        if (vec) {
            const float* vf = vc + (u64)q * 3u;
            if (vf[0] != 0.0f || vf[1] != 0.0f || vf[2] != 0.0f) {
                double v0 = (double)vf[0], v1 = (double)vf[1], v2 = (double)vf[2];
                double term = v0 * vd[0][ox] * vm[1][oy] * vm[2][oz] +
                              v1 * vm[0][ox] * vd[1][oy] * vm[2][oz] +
                              v2 * vm[0][ox] * vm[1][oy] * vd[2][oz];
                s[0] += term;
                if (fix) s[1] += term;
            }
        }
    }
}

// The right-hand sides of the cascade's pass over one depth (cycles.rs `right_hand_sides`;
// its first value is solver.rs `right_hand_side`'s): `r` against which the depth is relaxed
// (constraints `tcons`, plus the coarser V `vc`, minus what the coarser solution `pc` meets,
// plus the screening targets `Σ_c ω_c B_i(p_c) (τ − χ_{<d}(p_c))` with `cchi` = χ_{<d}), and
// when `b` is not null its fixed part, which further cycles keep.
extern "C" __global__ void first_right_hand_sides(
    u32 count, const u32* __restrict__ nbrs, const u32* __restrict__ brood_key, int depth,
    i64 lo, i64 hi, const u64* __restrict__ rank_bits, const u32* __restrict__ rank_before,
    u64 rank_words, const double* __restrict__ omega, const int* __restrict__ cfirst,
    const float* __restrict__ cvals, const u32* __restrict__ brood_parent,
    const u32* __restrict__ pnbrs, const double* __restrict__ pstencil,
    const double* __restrict__ pvstencil, const u32* __restrict__ nonzero_start,
    const u32* __restrict__ nonzero, const double* __restrict__ pmass,
    const double* __restrict__ pstiff, const double* __restrict__ pvmass,
    const double* __restrict__ pvderiv, const float* __restrict__ tcons,
    const double* __restrict__ pc, const float* __restrict__ vc,
    const double* __restrict__ cchi, float* __restrict__ r, float* __restrict__ b) {
    u32 n = blockIdx.x * blockDim.x + threadIdx.x;
    if (n >= count) return;
    i64 i[3];
    func_index(brood_key, depth, n, i);
    if (!in_range(i, lo, hi)) {
        r[n] = 0.0f;
        if (b) b[n] = 0.0f;
        return;
    }
    Parent p = {brood_parent, pnbrs, pstencil, pvstencil, nonzero_start, nonzero,
                pmass,        pstiff, pvmass,   pvderiv};
    Clusters cl = {rank_bits, rank_before, rank_words, omega, cfirst, cvals};
    double t = (double)tcons[n];
    double s[2] = {t, t};
    coarse_coupling(s, true, true, true, n, i, lo, hi, p, pc, vc);
    double rr = s[0], bb = s[1];
    for_each_cluster(nbrs, n, i, cl, [&](u32 c, double bv) {
        rr += omega[c] * bv * (TAU - cchi[c]);
        bb += omega[c] * bv * TAU;
    });
    r[n] = (float)rr;
    if (b) b[n] = (float)bb;
}

// The right-hand side a further cycle relaxes a depth against (cycles.rs
// `Cycles::level_right_hand_side`): the fixed part `b`, minus what the coarser solution `pc`
// meets (with χ_{<d} = `cchi` at the clusters), minus the finer depths' coupling `u` (when not
// null).
extern "C" __global__ void cycle_right_hand_side(
    u32 count, const u32* __restrict__ nbrs, const u32* __restrict__ brood_key, int depth,
    i64 lo, i64 hi, const u64* __restrict__ rank_bits, const u32* __restrict__ rank_before,
    u64 rank_words, const double* __restrict__ omega, const int* __restrict__ cfirst,
    const float* __restrict__ cvals, const u32* __restrict__ brood_parent,
    const u32* __restrict__ pnbrs, const double* __restrict__ pstencil,
    const double* __restrict__ pvstencil, const u32* __restrict__ nonzero_start,
    const u32* __restrict__ nonzero, const double* __restrict__ pmass,
    const double* __restrict__ pstiff, const double* __restrict__ pvmass,
    const double* __restrict__ pvderiv, const float* __restrict__ b,
    const double* __restrict__ pc, const double* __restrict__ cchi,
    const double* __restrict__ u, float* __restrict__ r) {
    u32 n = blockIdx.x * blockDim.x + threadIdx.x;
    if (n >= count) return;
    i64 i[3];
    func_index(brood_key, depth, n, i);
    if (!in_range(i, lo, hi)) {
        r[n] = 0.0f;
        return;
    }
    Parent p = {brood_parent, pnbrs, pstencil, pvstencil, nonzero_start, nonzero,
                pmass,        pstiff, pvmass,   pvderiv};
    Clusters cl = {rank_bits, rank_before, rank_words, omega, cfirst, cvals};
    double s[2] = {(double)b[n], 0.0};
    coarse_coupling(s, true, false, false, n, i, lo, hi, p, pc, nullptr);
    double rr = s[0];
    for_each_cluster(nbrs, n, i, cl, [&](u32 c, double bv) { rr -= omega[c] * bv * cchi[c]; });
    if (u) rr -= u[n];
    r[n] = (float)rr;
}

// The divergence constraints of one depth (system.rs `divergence_constraints`, ALGORITHM.md
// §6), fine to coarse, in two kernels: `push_finer_v` adds the next depth's V into `g`, colour
// by colour, and `constraint_rows` finishes each node's row.

// An entry of a coarse-against-fine 1-D table (system.rs `CoarseFine::get`): rows from coarse
// index `lo`, eight offsets `k = −3..=4` each, zero outside.
__device__ __forceinline__ double coarse_fine(const double* __restrict__ t, i64 lo, u64 rows,
                                              i64 i, i64 k) {
    if (k < -3 || k > 4) return 0.0;
    u64 r = (u64)(i - lo);
    if (r >= rows) return 0.0;
    return t[r * 8u + (u64)(k + 3)];
}

// One launch per colour of system.rs `brood_tiles`: each thread pushes the broods of one tile
// of the next depth (runs[2·(first + thread)] up to runs[2·(first + thread) + 1]) in order,
// each brood's V into the 5×5×5 window of its parent (system.rs `push_finer_v` and
// `push_brood`: one axis at a time, the same operations in the same order). Tiles of one
// colour push into disjoint windows, so every entry receives its terms in the CPU's order.
extern "C" __global__ void push_finer_v(
    const u32* __restrict__ runs, u64 first, u32 count, const u32* __restrict__ next_parent,
    const u32* __restrict__ nbrs, const u32* __restrict__ brood_key, int depth, i64 clo,
    u64 crows, const double* __restrict__ cvmass, const double* __restrict__ cvderiv,
    const float* __restrict__ v_finer, double* g) {
    u32 t = blockIdx.x * blockDim.x + threadIdx.x;
    if (t >= count) return;
    u32 b0 = runs[(first + t) * 2u], b1 = runs[(first + t) * 2u + 1u];
    for (u32 b = b0; b < b1; b++) {
        const float* vf = v_finer + (u64)b * 24u;
        bool any = false;
        for (int e = 0; e < 24; e++) any = any || vf[e] != 0.0f;
        if (!any) continue;
        u32 p = next_parent[b];
        i64 ip[3];
        func_index(brood_key, depth, p, ip);
        // Per axis, coarse offset r + 2 and child bit: the tables at k = bit − 2r.
        double m[3][5][2], dv[3][5][2];
        for (int a = 0; a < 3; a++) {
            for (int r = 0; r < 5; r++) {
                i64 ia = ip[a] + r - 2;
                for (int bit = 0; bit < 2; bit++) {
                    i64 k = bit - 2 * (r - 2);
                    m[a][r][bit] = coarse_fine(cvmass, clo, crows, ia, k);
                    dv[a][r][bit] = coarse_fine(cvderiv, clo, crows, ia, k);
                }
            }
        }
        double ax[2][2][5], ay[2][2][5], az[2][2][5];
        for (int bz = 0; bz < 2; bz++) {
            for (int by = 0; by < 2; by++) {
                int c = 2 * by + 4 * bz;
                for (int x = 0; x < 5; x++) {
                    double m0 = m[0][x][0], m1 = m[0][x][1], d0 = dv[0][x][0], d1 = dv[0][x][1];
                    ax[bz][by][x] = (double)vf[c * 3] * d0 + (double)vf[(c + 1) * 3] * d1;
                    ay[bz][by][x] = (double)vf[c * 3 + 1] * m0 + (double)vf[(c + 1) * 3 + 1] * m1;
                    az[bz][by][x] = (double)vf[c * 3 + 2] * m0 + (double)vf[(c + 1) * 3 + 2] * m1;
                }
            }
        }
        double pxy[2][5][5], pz[2][5][5];
        for (int bz = 0; bz < 2; bz++) {
            for (int y = 0; y < 5; y++) {
                double m0 = m[1][y][0], m1 = m[1][y][1], d0 = dv[1][y][0], d1 = dv[1][y][1];
                for (int x = 0; x < 5; x++) {
                    pxy[bz][y][x] = (ax[bz][0][x] * m0 + ax[bz][1][x] * m1) +
                                    (ay[bz][0][x] * d0 + ay[bz][1][x] * d1);
                    pz[bz][y][x] = az[bz][0][x] * m0 + az[bz][1][x] * m1;
                }
            }
        }
        for (int z = 0; z < 5; z++) {
            double m0 = m[2][z][0], m1 = m[2][z][1], d0 = dv[2][z][0], d1 = dv[2][z][1];
            for (int y = 0; y < 5; y++) {
                for (int x = 0; x < 5; x++) {
                    double val = (pxy[0][y][x] * m0 + pxy[1][y][x] * m1) +
                                 (pz[0][y][x] * d0 + pz[1][y][x] * d1);
                    if (val == 0.0) continue;
                    u32 q = neighbour(nbrs, p, x + 5 * y + 25 * z);
                    if (q == NONE) continue;
                    g[q] = g[q] + val;
                }
            }
        }
    }
}

// `Σ_j c_ij y_j` over the next depth's children `j` of function `i` (node `n`) (system.rs
// `restrict_one`), with the two-scale children of each index from the host's tables (bspline.rs
// `Basis::children`): ch_count[i − lo], and four (index, weight) slots.
__device__ __forceinline__ double restrict_one(const u32* __restrict__ nbrs,
                                               const u32* __restrict__ children, u64 nchildren,
                                               u32 n, const i64 i[3], i64 lo,
                                               const u32* __restrict__ ch_count,
                                               const i64* __restrict__ ch_j,
                                               const double* __restrict__ ch_w,
                                               const double* __restrict__ y) {
    u32 cnt[3];
    const i64* js[3];
    const double* ws[3];
    for (int a = 0; a < 3; a++) {
        u64 k = (u64)(i[a] - lo);
        cnt[a] = ch_count[k];
        js[a] = ch_j + k * 4u;
        ws[a] = ch_w + k * 4u;
    }
    double s = 0.0;
    for (u32 cz = 0; cz < cnt[2]; cz++) {
        for (u32 cy = 0; cy < cnt[1]; cy++) {
            for (u32 cx = 0; cx < cnt[0]; cx++) {
                i64 j[3] = {js[0][cx], js[1][cy], js[2][cz]};
                i64 o0 = (j[0] >> 1) - i[0], o1 = (j[1] >> 1) - i[1], o2 = (j[2] >> 1) - i[2];
                u32 m = neighbour(nbrs, n, (int)((o0 + 2) + 5 * (o1 + 2) + 25 * (o2 + 2)));
                if (m == NONE) continue;
                u32 b = (u64)m < nchildren ? children[m] : NONE;
                if (b == NONE) continue;
                u32 bits = (u32)((j[0] & 1) | ((j[1] & 1) << 1) | ((j[2] & 1) << 2));
                u32 f = b * 8u + bits;
                s += ws[0][cx] * ws[1][cy] * ws[2][cz] * y[f];
            }
        }
    }
    return s;
}

// Each node's constraints (system.rs `divergence_constraints`, its `rows`): `G` (V of the
// finer depths: the next depth's, which `push_finer_v` left in `g` when `pushed` is set, plus
// the restriction of the next depth's `G`, `gf`) into `g`, and `T = G + ∫∇B_i·V_d` into `b`,
// the last term where a brood around the node's has a nonzero V. Null `gf`, `v` or `g` stand
// for none (the CPU's empty arrays); `g` is not null when `pushed` is set. Each thread reads
// and writes only its own node's `g`.
extern "C" __global__ void constraint_rows(
    u32 count, const u32* __restrict__ nbrs, const u32* __restrict__ brood_key, int depth,
    i64 lo, i64 hi,
    // Same-depth FEM-against-V 1-D tables, rows lo..=hi, five offsets each.
    const double* __restrict__ vmass, const double* __restrict__ vderiv,
    // Each node's children brood (empty: none), and the two-scale children per index.
    const u32* __restrict__ children, u64 nchildren, const u32* __restrict__ ch_count,
    const i64* __restrict__ ch_j, const double* __restrict__ ch_w,
    int pushed, const double* __restrict__ gf, const float* __restrict__ v, double* g,
    float* __restrict__ b) {
    u32 n = blockIdx.x * blockDim.x + threadIdx.x;
    if (n >= count) return;
    i64 i[3];
    func_index(brood_key, depth, n, i);
    if (!in_range(i, lo, hi)) {
        if (g) g[n] = 0.0;
        b[n] = 0.0f;
        return;
    }
    double gg = pushed ? g[n] : 0.0;
    if (gf) gg += restrict_one(nbrs, children, nchildren, n, i, lo, ch_count, ch_j, ch_w, gf);
    double bb = gg;
    const u32* around = nbrs + (u64)(n >> 3) * 27u;
    bool near_v = false;
    if (v) {
        for (int s = 0; s < 27 && !near_v; s++) {
            u32 q = around[s];
            if (q == NONE) continue;
            for (int e = 0; e < 24; e++) near_v = near_v || v[(u64)q * 24u + e] != 0.0f;
        }
    }
    if (near_v) {
        // system.rs `v_brood_term` for this node: the window's sum one axis at a time, over
        // the 6×6×6 nodes of the 27 broods around (local coordinate 2·slot + child bit).
        int bit[3] = {(int)(n & 1u), (int)((n >> 1) & 1u), (int)((n >> 2) & 1u)};
        double m[3][5], dv[3][5];
        for (int a = 0; a < 3; a++) {
            for (int o = 0; o < 5; o++) {
                m[a][o] = table(vmass, lo, hi, i[a], o - 2);
                dv[a][o] = table(vderiv, lo, hi, i[a], o - 2);
            }
        }
        double uxy[5], uz[5];
        for (int zz = 0; zz < 5; zz++) {
            int z = bit[2] + zz;
            double tx[5], ty[5], tz[5];
            for (int yy = 0; yy < 5; yy++) {
                int y = bit[1] + yy;
                double sx = 0.0, sy = 0.0, sz = 0.0;
                for (int o = 0; o < 5; o++) {
                    int x = bit[0] + o;
                    u32 q = around[x / 2 + 3 * (y / 2) + 9 * (z / 2)];
                    double v0 = 0.0, v1 = 0.0, v2 = 0.0;
                    if (q != NONE) {
                        const float* vn =
                            v + ((u64)q * 8u + (u32)(x % 2 + 2 * (y % 2) + 4 * (z % 2))) * 3u;
                        v0 = (double)vn[0];
                        v1 = (double)vn[1];
                        v2 = (double)vn[2];
                    }
                    sx += v0 * dv[0][o];
                    sy += v1 * m[0][o];
                    sz += v2 * m[0][o];
                }
                tx[yy] = sx;
                ty[yy] = sy;
                tz[yy] = sz;
            }
            double sxy = 0.0, s2 = 0.0;
            for (int o = 0; o < 5; o++) {
                sxy += tx[o] * m[1][o] + ty[o] * dv[1][o];
                s2 += tz[o] * m[1][o];
            }
            uxy[zz] = sxy;
            uz[zz] = s2;
        }
        double s3 = 0.0;
        for (int o = 0; o < 5; o++) s3 += uxy[o] * m[2][o] + uz[o] * dv[2][o];
        bb = gg + s3;
    }
    if (g) g[n] = gg;
    b[n] = (float)bb;
}

// The finer depths' gradient coupling of the parent depth (cycles.rs `coupling_below_of`),
// in two kernels: `push_to_parents` pushes a depth's coefficients into its parents' windows,
// colour by colour, and `coupling_rows` adds the restriction of the next finer coupling.

// One launch per colour of cycles.rs `push_tiles`: each thread pushes the broods of one tile
// (runs[2·(first + thread)] up to runs[2·(first + thread) + 1]) in order, each brood's
// coefficients into its parent's 5×5×5 window one axis at a time (cycles.rs `push_to_parents`
// and `Op::parent_stiffness_push`: the same operations in the same order). Tiles of one colour
// push into disjoint windows, so every entry receives its terms in the CPU's order.
extern "C" __global__ void push_to_parents(
    const u32* __restrict__ runs, u64 first, u32 count, const float* __restrict__ x,
    const u32* __restrict__ brood_key, int depth, i64 lo, i64 hi,
    const u32* __restrict__ brood_parent, const u32* __restrict__ pnbrs,
    const double* __restrict__ pmass, const double* __restrict__ pstiff, double* g) {
    u32 t = blockIdx.x * blockDim.x + threadIdx.x;
    if (t >= count) return;
    u32 b0 = runs[(first + t) * 2u], b1 = runs[(first + t) * 2u + 1u];
    for (u32 b = b0; b < b1; b++) {
        double xs[8];
        bool any = false;
        for (u32 c = 0; c < 8u; c++) {
            xs[c] = (double)x[b * 8u + c];
            any = any || xs[c] != 0.0;
        }
        if (!any) continue;
        i64 i0[3];
        func_index(brood_key, depth, b * 8u, i0);
        for (u32 c = 0; c < 8u; c++) {
            i64 i[3] = {i0[0] + (i64)(c & 1u), i0[1] + (i64)((c >> 1) & 1u),
                        i0[2] + (i64)((c >> 2) & 1u)};
            if (!in_range(i, lo, hi)) xs[c] = 0.0;
        }
        double m[3][2][5], k[3][2][5];
        for (int a = 0; a < 3; a++) {
            for (int bit = 0; bit < 2; bit++) {
                for (int r = 0; r < 5; r++) {
                    m[a][bit][r] = table(pmass, lo, hi, i0[a] + bit, r - 2);
                    k[a][bit][r] = table(pstiff, lo, hi, i0[a] + bit, r - 2);
                }
            }
        }
        double ax[2][2][5], bx[2][2][5];
        for (int bz = 0; bz < 2; bz++) {
            for (int by = 0; by < 2; by++) {
                int c = 2 * by + 4 * bz;
                for (int r = 0; r < 5; r++) {
                    ax[bz][by][r] = xs[c] * k[0][0][r] + xs[c + 1] * k[0][1][r];
                    bx[bz][by][r] = xs[c] * m[0][0][r] + xs[c + 1] * m[0][1][r];
                }
            }
        }
        double pxy[2][5][5], pz[2][5][5];
        for (int bz = 0; bz < 2; bz++) {
            for (int y = 0; y < 5; y++) {
                for (int r = 0; r < 5; r++) {
                    pxy[bz][y][r] = (ax[bz][0][r] * m[1][0][y] + ax[bz][1][r] * m[1][1][y]) +
                                    (bx[bz][0][r] * k[1][0][y] + bx[bz][1][r] * k[1][1][y]);
                    pz[bz][y][r] = bx[bz][0][r] * m[1][0][y] + bx[bz][1][r] * m[1][1][y];
                }
            }
        }
        u32 par = brood_parent[b];
        for (int z = 0; z < 5; z++) {
            for (int y = 0; y < 5; y++) {
                for (int r = 0; r < 5; r++) {
                    double val = (pxy[0][y][r] * m[2][0][z] + pxy[1][y][r] * m[2][1][z]) +
                                 (pz[0][y][r] * k[2][0][z] + pz[1][y][r] * k[2][1][z]);
                    if (val == 0.0) continue;
                    u32 q = neighbour(pnbrs, par, r + 5 * y + 25 * z);
                    if (q != NONE) g[q] = g[q] + val;
                }
            }
        }
    }
}

// Adds to each parent-depth node's `g` the restriction of the finer coupling `u` (one value
// per node of the depth below it), for the nodes whose function is in `lo..=hi` (cycles.rs
// `coupling_below_of`; the rows as in `constraint_rows`). Each thread writes its own node.
extern "C" __global__ void coupling_rows(
    u32 count, const u32* __restrict__ nbrs, const u32* __restrict__ brood_key, int depth,
    i64 lo, i64 hi, const u32* __restrict__ children, u64 nchildren,
    const u32* __restrict__ ch_count, const i64* __restrict__ ch_j,
    const double* __restrict__ ch_w, const double* __restrict__ u, double* g) {
    u32 n = blockIdx.x * blockDim.x + threadIdx.x;
    if (n >= count) return;
    i64 i[3];
    func_index(brood_key, depth, n, i);
    if (!in_range(i, lo, hi)) return;
    g[n] = g[n] + restrict_one(nbrs, children, nchildren, n, i, lo, ch_count, ch_j, ch_w, u);
}

// The coarser solution χ_{<d} at the depth's screening clusters (solver.rs
// `coarse_cluster_values`): at each cluster's position, the parent depth's cumulative
// coefficients `pc` over the window of the parent of the cluster's node (solver.rs
// `coarse_value`). `boundary` is 0 (free), 1 (Neumann) or 2 (Dirichlet).

// The B-splines of a grid of `n` cells that are nonzero at `x` (bspline.rs `Basis::window`):
// their values into `v` (DEGREE + 1 of them); returns the first one's index.
__device__ __forceinline__ i64 window(i64 n, int boundary, double x, double v[3]) {
    // bspline.rs `locate`: clamped to the unit interval, then to the grid's cells.
    double xc = x < 0.0 ? 0.0 : (x > 1.0 ? 1.0 : x);
    double u = xc * (double)n;
    i64 c = (i64)floor(u);
    if (c < 0) c = 0;
    if (c > n - 1) c = n - 1;
    double t = u - (double)c;
#if DEGREE == 1
    v[0] = 1.0 - t;
    v[1] = t;
    v[2] = 0.0;
    if (boundary == 2) {
        if (c == 0) v[0] = 0.0;
        if (c == n - 1) v[1] = 0.0;
    }
    return c;
#else
    double s = 1.0 - t;
    double m = t - 0.5;
    v[0] = 0.5 * s * s;
    v[1] = 0.75 - m * m;
    v[2] = 0.5 * t * t;
    if (boundary != 0) {
        double sign = boundary == 1 ? 1.0 : -1.0;
        if (c == 0) {
            v[1] += sign * v[0];
            v[0] = 0.0;
        }
        if (c == n - 1) {
            v[1] += sign * v[2];
            v[2] = 0.0;
        }
    }
    return c - 1;
#endif
}

extern "C" __global__ void coarse_cluster_values(
    u32 count, const u32* __restrict__ cl_node, const double* __restrict__ pos,
    const u32* __restrict__ brood_parent, const u32* __restrict__ pnbrs,
    const u32* __restrict__ pkeys, int pdepth, int boundary, const double* __restrict__ pc,
    double* __restrict__ out) {
    u32 c = blockIdx.x * blockDim.x + threadIdx.x;
    if (c >= count) return;
    u32 par = brood_parent[cl_node[c] >> 3];
    i64 own[3];
    func_index(pkeys, pdepth, par, own);
    i64 n = (i64)1 << pdepth;
    double v[3][3];
    i64 f[3];
    for (int a = 0; a < 3; a++) f[a] = window(n, boundary, pos[(u64)c * 3u + a], v[a]);
    double s = 0.0;
    for (int z = 0; z <= DEGREE; z++) {
        for (int y = 0; y <= DEGREE; y++) {
            for (int xx = 0; xx <= DEGREE; xx++) {
                i64 o0 = f[0] + xx - own[0], o1 = f[1] + y - own[1], o2 = f[2] + z - own[2];
                u32 m = neighbour(pnbrs, par, (int)((o0 + 2) + 5 * (o1 + 2) + 25 * (o2 + 2)));
                if (m == NONE) continue;
                s += v[0][xx] * v[1][y] * v[2][z] * pc[m];
            }
        }
    }
    out[c] = s;
}

// The prolongation of a depth's parent depth's cumulative coefficients to the depth, plus the
// depth's own (system.rs `prolong`, as solver.rs `prolong_solution` and `prolong_field` call
// it): per node, its own coefficient plus the parent window's coarse coefficients weighted by
// the two-scale weights; zero for the nodes whose function is outside `lo..=hi`.

// The weight of coarse index (j >> 1) + o for fine index j (system.rs `Prolong::get`): rows
// from `wlo`, `wlen` of them, three offsets each.
__device__ __forceinline__ double prolong_weight(const double* __restrict__ w, i64 wlo, u64 wlen,
                                                 i64 j, int o) {
    u64 r = (u64)(j - wlo);
    if (r >= wlen) return 0.0;
    return w[r * 3u + (u64)(o + 1)];
}

// Calls f(q, weight) for the parent window's nodes that a fine function `j` (node of parent
// `par`) takes a nonzero weight from, in the CPU's order (system.rs `prolong_one`).
template <typename F>
__device__ __forceinline__ void for_each_prolong(const i64 j[3], u32 par,
                                                 const u32* __restrict__ pnbrs,
                                                 const double* __restrict__ w, i64 wlo,
                                                 u64 wlen, F f) {
    for (int oz = -1; oz <= 1; oz++) {
        double wz = prolong_weight(w, wlo, wlen, j[2], oz);
        if (wz == 0.0) continue;
        for (int oy = -1; oy <= 1; oy++) {
            double wy = prolong_weight(w, wlo, wlen, j[1], oy);
            if (wy == 0.0) continue;
            for (int ox = -1; ox <= 1; ox++) {
                double wx = prolong_weight(w, wlo, wlen, j[0], ox);
                if (wx == 0.0) continue;
                u32 q = neighbour(pnbrs, par, (ox + 2) + 5 * (oy + 2) + 25 * (oz + 2));
                if (q == NONE) continue;
                f(q, wx * wy * wz);
            }
        }
    }
}

// The cumulative solution (solver.rs `prolong_solution`): `pc` of the parent depth
// prolonged, plus the depth's coefficients `x`, in double precision.
extern "C" __global__ void prolong_solution(
    u32 count, const u32* __restrict__ brood_key, int depth, i64 lo, i64 hi,
    const u32* __restrict__ brood_parent, const u32* __restrict__ pnbrs,
    const double* __restrict__ w, i64 wlo, u64 wlen, const double* __restrict__ pc,
    const float* __restrict__ x, double* __restrict__ out) {
    u32 n = blockIdx.x * blockDim.x + threadIdx.x;
    if (n >= count) return;
    i64 j[3];
    func_index(brood_key, depth, n, j);
    if (!in_range(j, lo, hi)) {
        out[n] = 0.0;
        return;
    }
    double acc = (double)x[n];
    for_each_prolong(j, brood_parent[n >> 3], pnbrs, w, wlo, wlen,
                     [&](u32 q, double wt) { acc += wt * pc[q]; });
    out[n] = acc;
}

// The cumulative V (solver.rs `prolong_field`): `vc` of the parent depth prolonged, plus the
// depth's own V `vt` (null: none), three components per node, summed in double precision and
// stored in single.
extern "C" __global__ void prolong_field(
    u32 count, const u32* __restrict__ brood_key, int depth, i64 lo, i64 hi,
    const u32* __restrict__ brood_parent, const u32* __restrict__ pnbrs,
    const double* __restrict__ w, i64 wlo, u64 wlen, const float* __restrict__ vc,
    const float* __restrict__ vt, float* __restrict__ out) {
    u32 n = blockIdx.x * blockDim.x + threadIdx.x;
    if (n >= count) return;
    i64 j[3];
    func_index(brood_key, depth, n, j);
    float* o = out + (u64)n * 3u;
    if (!in_range(j, lo, hi)) {
        o[0] = 0.0f;
        o[1] = 0.0f;
        o[2] = 0.0f;
        return;
    }
    double acc[3] = {0.0, 0.0, 0.0};
    if (vt) {
        for (int k = 0; k < 3; k++) acc[k] = (double)vt[(u64)n * 3u + k];
    }
    for_each_prolong(j, brood_parent[n >> 3], pnbrs, w, wlo, wlen, [&](u32 q, double wt) {
        for (int k = 0; k < 3; k++) acc[k] += wt * (double)vc[(u64)q * 3u + k];
    });
    for (int k = 0; k < 3; k++) o[k] = (float)acc[k];
}
