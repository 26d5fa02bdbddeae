//! Iso-vertices: one per finest edge with a sign change, placed by the quadratic fit of the
//! field along the edge (ALGORITHM.md §9.2) and owned by exactly one leaf.

use super::blocks::{ChunkOut, CornerCache, Ctx, Scratch};
use super::Cells;
use crate::vec3::norm;

/// One crossing on a finest edge, as seen by a leaf.
#[derive(Clone, Copy)]
pub(super) struct Crossing {
    pub(super) key: u64,
    pub(super) lo: [u32; 3],
    pub(super) axis: u8,
    pub(super) len: u32,
    pub(super) i0: u32,
    pub(super) i1: u32,
}

/// Root of the fitted edge function in `[0, 1]` (ALGORITHM.md §9.2). `x0, x1` are the
/// endpoint values minus iso (opposite signs), `g0, g1` the derivatives along the edge in
/// edge-parameter units.
pub(super) fn edge_root(x0: f64, x1: f64, g0: f64, g1: f64, linear: bool) -> f64 {
    let lin = x0 / (x0 - x1);
    let lin = if lin.is_nan() {
        0.5
    } else {
        lin.clamp(0.0, 1.0)
    };
    if linear {
        return lin;
    }
    let delta = x1 - x0;
    let scale = delta / ((g0 + g1) * 0.5);
    if !scale.is_finite() {
        return lin;
    }
    let (g0, g1) = (g0 * scale, g1 * scale);
    let a = 3.0 * delta - g1 - 2.0 * g0;
    let b = g0;
    let c = x0;
    const EPS: f64 = 1e-12;
    let ok = |t: f64| t.is_finite() && (-EPS..=1.0 + EPS).contains(&t);
    let (mut sum, mut count) = (0.0, 0);
    if a == 0.0 {
        if b != 0.0 && ok(-c / b) {
            sum = -c / b;
            count = 1;
        }
    } else {
        let disc = b * b - 4.0 * a * c;
        if disc >= 0.0 {
            let sq = disc.sqrt();
            let q = -0.5 * (b + if b >= 0.0 { sq } else { -sq });
            let r1 = q / a;
            let r2 = if q != 0.0 { c / q } else { r1 };
            for r in [r1, r2] {
                if ok(r) {
                    sum += r;
                    count += 1;
                }
            }
        }
    }
    if count == 0 {
        lin
    } else {
        (sum / count as f64).clamp(0.0, 1.0)
    }
}

/// Places the iso-vertices of the leaf at `lo` (size `s`): sorts and dedups `sc.cross` by key,
/// fills `sc.pos` (and `sc.nrm` with normals on), and emits the vertices the leaf owns.
pub(super) fn place_vertices<C: Cells>(
    ctx: &Ctx<C>,
    sc: &mut Scratch<C::Handle>,
    lo: [u32; 3],
    s: u32,
    out: &mut ChunkOut,
) {
    sc.cross.sort_unstable_by_key(|c| c.key);
    sc.cross.dedup_by_key(|c| c.key);
    sc.pos.clear();
    sc.nrm.clear();
    for k in 0..sc.cross.len() {
        let c = sc.cross[k];
        let (p, n) = crossing_point(ctx, &mut sc.corners, &c);
        sc.pos.push(p);
        if ctx.normals {
            sc.nrm.push(n);
        }
        if owns(ctx, lo, s, &c) {
            out.owned_keys.push(c.key);
            out.owned_pos.push(p);
            if ctx.normals {
                out.owned_nrm.push(unit_f32(n));
            }
        }
    }
}

/// The iso-vertex position on a crossing's edge.
fn crossing_point<C: Cells>(
    ctx: &Ctx<C>,
    corners: &mut CornerCache<C::Handle>,
    c: &Crossing,
) -> ([f64; 3], [f64; 3]) {
    let axis = c.axis as usize;
    let (x0, x1) = (corners.d[c.i0 as usize], corners.d[c.i1 as usize]);
    let h = c.len as f64 * ctx.inv;
    let t = if ctx.linear {
        edge_root(x0, x1, 0.0, 0.0, true)
    } else {
        let g0 = corners.slope(ctx, c.i0, axis) * h;
        let g1 = corners.slope(ctx, c.i1, axis) * h;
        edge_root(x0, x1, g0, g1, false)
    };
    let mut p = c.lo.map(|x| x as f64 * ctx.inv);
    p[axis] += t * h;
    let mut n = [0.0; 3];
    if ctx.normals {
        let (g0, g1) = (corners.grad(ctx, c.i0), corners.grad(ctx, c.i1));
        let g: [f64; 3] = std::array::from_fn(|a| -((1.0 - t) * g0[a] + t * g1[a]));
        let len = norm(g);
        if len > 0.0 && len.is_finite() {
            n = g.map(|x| x / len);
        }
    }
    (p, n)
}

/// A unit vector as `f32`, or zero when `v` has no direction.
pub(super) fn unit_f32(v: [f64; 3]) -> [f32; 3] {
    let len = norm(v);
    if len > 0.0 && len.is_finite() {
        v.map(|x| (x / len) as f32)
    } else {
        [0.0; 3]
    }
}

/// Whether the leaf at `lo` (size `s`) owns the edge vertex of `c`: it contains the edge's
/// midpoint nudged towards + along both other axes (towards − on the cube's far faces).
fn owns<C: Cells>(ctx: &Ctx<C>, lo: [u32; 3], s: u32, c: &Crossing) -> bool {
    let a = c.axis as usize;
    (0..3).filter(|&b| b != a).all(|b| {
        let e = c.lo[b];
        if e < ctx.full {
            lo[b] <= e && e < lo[b] + s
        } else {
            lo[b] + s == ctx.full
        }
    })
}
