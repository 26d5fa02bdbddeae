// Gauss–Seidel relaxation of one octree depth on the GPU (ALGORITHM.md §7.1).
//
// One thread relaxes one node. A launch covers the nodes of one (block colour, node colour)
// class of `solver::Op::gauss_seidel`; nodes of one node colour share no stiffness entry and no
// screening cluster, so a launch has no races, and launching the classes in the CPU's order
// reproduces the CPU's sweep exactly. Every operation below mirrors `Op::relax`,
// `Op::stiffness_row` and `Op::for_each_cluster` in the same order, and the host compiles
// this file with `--fmad=false`, so the coefficients are the CPU's to the last bit.
//
// The host prepends the window tables `WSLOT` and `WBITS` (octree::WINDOW) and `DEGREE`.

#define NONE 0xffffffffu

typedef unsigned int u32;
typedef unsigned long long u64;
typedef long long i64;

// The node `w` (window index of an offset in [-2,2]^3) away from node `n`, or NONE.
__device__ __forceinline__ u32 neighbour(const u32* __restrict__ nbrs, u32 n, int w) {
    u32 c = n & 7u;
    u32 b = nbrs[(u64)(n >> 3) * 27u + WSLOT[c * 125u + w]];
    return b == NONE ? NONE : b * 8u + WBITS[c * 125u + w];
}

// A 1-D table entry for index `i` and offset `off` (solver's `Table1D::get`): rows
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

// The cluster of node `m` (octree.rs `NodeRank::get`), or NONE.
__device__ __forceinline__ u32 cluster_of(const u64* __restrict__ bits,
                                          const u32* __restrict__ before, u64 words, u32 m) {
    u64 k = m >> 6;
    if (k >= words) return NONE;
    u64 word = bits[k];
    u64 bit = 1ull << (m & 63u);
    if ((word & bit) == 0) return NONE;
    return before[k] + (u32)__popcll(word & (bit - 1));
}

extern "C" __global__ void relax(
    // The nodes of this launch: list[first .. first + count].
    const u32* __restrict__ list, u64 first, u32 count,
    // The level: 27 neighbouring broods and the key of each brood's parent.
    const u32* __restrict__ nbrs, const u32* __restrict__ brood_key, int depth,
    // Function index range and the interior stiffness stencil (125 entries).
    i64 lo, i64 hi, const double* __restrict__ stencil,
    // Same-depth 1-D mass and stiffness tables, rows lo..=hi.
    const double* __restrict__ mass, const double* __restrict__ stiff,
    // Clusters: the node rank bitmap, ω, first function index and basis values per axis.
    const u64* __restrict__ rank_bits, const u32* __restrict__ rank_before, u64 rank_words,
    const double* __restrict__ omega, const int* __restrict__ cfirst,
    const float* __restrict__ cvals,
    // Right-hand side (per node), coefficients (per node), χ at the clusters.
    const double* __restrict__ rhs, float* x, double* chi) {
    u32 t = blockIdx.x * blockDim.x + threadIdx.x;
    if (t >= count) return;
    u32 n = list[first + t];
    const u32* key = brood_key + (u64)(n >> 3) * 3u;
    i64 half = (i64)1 << depth;
    i64 i[3] = {
        (i64)(2u * key[0] + (n & 1u)) - half,
        (i64)(2u * key[1] + ((n >> 1) & 1u)) - half,
        (i64)(2u * key[2] + ((n >> 2) & 1u)) - half,
    };
    for (int a = 0; a < 3; a++) {
        if (i[a] < lo || i[a] > hi) return;
    }
    bool interior = true;
    for (int a = 0; a < 3; a++) {
        if (i[a] - lo < 3 || hi - i[a] < 3) interior = false;
    }
    // Σ_j L_ij x_j over the same-depth window (Op::stiffness_row).
    double s = 0.0;
    for (i64 z = -DEGREE; z <= DEGREE; z++) {
        for (i64 y = -DEGREE; y <= DEGREE; y++) {
            for (i64 xx = -DEGREE; xx <= DEGREE; xx++) {
                int w = (int)((xx + 2) + 5 * (y + 2) + 25 * (z + 2));
                u32 m = neighbour(nbrs, n, w);
                if (m == NONE) continue;
                double xm = (double)x[m];
                if (interior) {
                    s += stencil[w] * xm;
                } else if (xm != 0.0) {
                    i64 o[3] = {xx, y, z};
                    s += stiffness(mass, stiff, lo, hi, i, o) * xm;
                }
            }
        }
    }
    double dg;
    if (interior) {
        dg = stencil[62];
    } else {
        i64 o[3] = {0, 0, 0};
        dg = stiffness(mass, stiff, lo, hi, i, o);
    }
    // The screening clusters around the node (Op::for_each_cluster), in the CPU's order.
    u32 touched_c[27];
    double touched_b[27];
    int k = 0;
    const i64 clo = -1;
    const i64 chi_hi = DEGREE == 1 ? 0 : 1;
    for (i64 z = clo; z <= chi_hi; z++) {
        for (i64 y = clo; y <= chi_hi; y++) {
            for (i64 xx = clo; xx <= chi_hi; xx++) {
                int w = (int)((xx + 2) + 5 * (y + 2) + 25 * (z + 2));
                u32 m = neighbour(nbrs, n, w);
                if (m == NONE) continue;
                u32 c = cluster_of(rank_bits, rank_before, rank_words, m);
                if (c == NONE) continue;
                // B_i(p_c) (system.rs `Clusters::basis_value`).
                double bv = 1.0;
                for (int a = 0; a < 3; a++) {
                    i64 kk = i[a] - (i64)cfirst[(u64)c * 3u + a];
                    if (kk < 0 || kk > DEGREE) {
                        bv = 0.0;
                        break;
                    }
                    bv *= (double)cvals[(u64)c * 9u + a * 3 + kk];
                }
                double wc = omega[c] * bv;
                s += wc * chi[c];
                dg += wc * bv;
                touched_c[k] = c;
                touched_b[k] = bv;
                k++;
            }
        }
    }
    double dx = (rhs[n] - s) / dg;
    x[n] = (float)((double)x[n] + dx);
    for (int j = 0; j < k; j++) {
        chi[touched_c[j]] = chi[touched_c[j]] + dx * touched_b[j];
    }
}
