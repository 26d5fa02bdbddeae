//! Coarse–fine consistency: the boundary of a leaf is tiled by face pieces shared exactly
//! with its neighbours, whose sides are split at every leaf corner on them, and marching
//! squares on each piece gives the leaf's oriented segments between edge crossings.

use super::blocks::{Ctx, Scratch};
use super::vertex::Crossing;
use super::{edge_key, Cells};

/// The leaf being polygonised: its handle, depth, offset, and which same-depth cells around it
/// are refined (see [`Cells::refined_around`]).
#[derive(Clone, Copy)]
pub(super) struct Here<H> {
    pub(super) h: H,
    pub(super) depth: u32,
    pub(super) offset: [u32; 3],
    pub(super) around: u32,
}

impl<H: Copy> Here<H> {
    /// Whether the cell of `depth` and `offset` is refined, answered from `around` when the
    /// cell has the leaf's depth.
    #[inline]
    fn refined<C: Cells<Handle = H>>(&self, cells: &C, depth: u32, offset: [u32; 3]) -> bool {
        if depth == self.depth {
            let mut s = 0;
            let mut mul = 1;
            for a in 0..3 {
                let r = i64::from(offset[a]) - i64::from(self.offset[a]) + 1;
                if !(0..3).contains(&r) {
                    return cells.refined(self.h, depth, offset);
                }
                s += r as u32 * mul;
                mul *= 3;
            }
            return self.around >> s & 1 != 0;
        }
        cells.refined(self.h, depth, offset)
    }
}

/// Depth of the cells of width `size` (in finest-cell units).
#[inline]
fn depth_of(ctx_max: u32, size: u32) -> u32 {
    ctx_max - size.trailing_zeros()
}

/// Visits the pieces tiling the square `origin + [0,size]²` (normal `n`) of a leaf face; the
/// leaf lies above the square when `flip`, below otherwise.
#[allow(clippy::too_many_arguments)]
pub(super) fn face<C: Cells>(
    ctx: &Ctx<C>,
    sc: &mut Scratch<C::Handle>,
    here: &Here<C::Handle>,
    origin: [u32; 3],
    size: u32,
    n: usize,
    flip: bool,
    known: Option<[u32; 4]>,
) {
    let (u, v) = ((n + 1) % 3, (n + 2) % 3);
    if size > 1 {
        // The square is subdivided iff the cell of its size across it is refined.
        let k = depth_of(ctx.max_depth, size);
        let across = if flip {
            origin[n].checked_sub(size)
        } else {
            (origin[n] < ctx.full).then_some(origin[n])
        };
        if let Some(a) = across {
            let mut cell = origin.map(|x| x / size);
            cell[n] = a / size;
            if here.refined(ctx.cells, k, cell) {
                let half = size / 2;
                for (du, dv) in [(0, 0), (1, 0), (1, 1), (0, 1)] {
                    let mut o = origin;
                    o[u] += du * half;
                    o[v] += dv * half;
                    face(ctx, sc, here, o, half, n, flip, None);
                }
                return;
            }
        }
    }
    piece(ctx, sc, here, origin, size, n, flip, known);
}

/// Whether the midpoint of the dyadic segment from `a` (length `len` along `axis`, towards +
/// when `forward`) is a leaf corner: iff one of the four cells of size `len` around the
/// segment is refined.
fn segment_split<C: Cells>(
    ctx: &Ctx<C>,
    here: &Here<C::Handle>,
    a: [u32; 3],
    axis: usize,
    forward: bool,
    len: u32,
) -> bool {
    let k = depth_of(ctx.max_depth, len);
    let mut e = a;
    if !forward {
        e[axis] -= len;
    }
    let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
    let cell_count = ctx.full / len;
    for du in 0..2u32 {
        for dv in 0..2u32 {
            let (Some(cu), Some(cv)) = ((e[u] / len).checked_sub(du), (e[v] / len).checked_sub(dv))
            else {
                continue;
            };
            if cu >= cell_count || cv >= cell_count {
                continue;
            }
            let mut cell = [0u32; 3];
            cell[axis] = e[axis] / len;
            cell[u] = cu;
            cell[v] = cv;
            if here.refined(ctx.cells, k, cell) {
                return true;
            }
        }
    }
    false
}

/// Pushes the leaf corners strictly inside the dyadic segment from `a` (length `len` along
/// `axis`, direction `forward`), in order from `a`.
#[allow(clippy::too_many_arguments)]
fn split_side<C: Cells>(
    ctx: &Ctx<C>,
    sc: &mut Scratch<C::Handle>,
    here: &Here<C::Handle>,
    a: [u32; 3],
    axis: usize,
    forward: bool,
    len: u32,
) {
    if len <= 1 || !segment_split(ctx, here, a, axis, forward, len) {
        return;
    }
    let half = len / 2;
    let mut m = a;
    if forward {
        m[axis] += half;
    } else {
        m[axis] -= half;
    }
    split_side(ctx, sc, here, a, axis, forward, half);
    let i = sc.corners.get(ctx, m);
    sc.bv.push((m, i));
    split_side(ctx, sc, here, m, axis, forward, half);
}

/// Marching squares on one face piece; appends its oriented segments and crossings.
#[allow(clippy::too_many_arguments)]
fn piece<C: Cells>(
    ctx: &Ctx<C>,
    sc: &mut Scratch<C::Handle>,
    here: &Here<C::Handle>,
    origin: [u32; 3],
    size: u32,
    n: usize,
    flip: bool,
    known: Option<[u32; 4]>,
) {
    let (u, v) = ((n + 1) % 3, (n + 2) % 3);
    let mut p = [origin; 4];
    p[1][u] += size;
    p[2][u] += size;
    p[2][v] += size;
    p[3][v] += size;
    let idx = match known {
        Some(k) => k,
        None => p.map(|c| sc.corners.get(ctx, c)),
    };
    // Boundary, counter-clockwise around +n.
    sc.bv.clear();
    let sides = [(u, true), (v, true), (u, false), (v, false)];
    for (c, &(axis, fwd)) in sides.iter().enumerate() {
        sc.bv.push((p[c], idx[c]));
        split_side(ctx, sc, here, p[c], axis, fwd, size);
    }
    let d = &sc.corners.d;
    let first = d[sc.bv[0].1 as usize] > 0.0;
    if sc.bv.iter().all(|b| (d[b.1 as usize] > 0.0) == first) {
        return;
    }
    sc.cr.clear();
    let nb = sc.bv.len();
    for i in 0..nb {
        let (pa, ia) = sc.bv[i];
        let (pb, ib) = sc.bv[(i + 1) % nb];
        let (ina, inb) = (d[ia as usize] > 0.0, d[ib as usize] > 0.0);
        if ina == inb {
            continue;
        }
        let axis = if pa[0] != pb[0] {
            0
        } else if pa[1] != pb[1] {
            1
        } else {
            2
        };
        let (lo, i0, i1, len) = if pa[axis] < pb[axis] {
            (pa, ia, ib, pb[axis] - pa[axis])
        } else {
            (pb, ib, ia, pa[axis] - pb[axis])
        };
        let key = edge_key(lo, axis);
        sc.cr.push((key, inb));
        sc.cross.push(Crossing {
            key,
            lo,
            axis: axis as u8,
            len,
            i0,
            i1,
        });
    }
    // Pairing rule (see module docs).
    let f = idx.map(|i| d[i as usize]);
    let fin = f.map(|x| x > 0.0);
    let join_outside = sc.cr.len() == 4
        && fin[0] == fin[2]
        && fin[1] == fin[3]
        && fin[0] != fin[1]
        && (f[0] * f[2] - f[1] * f[3]) / (f[0] + f[2] - f[1] - f[3]) > 0.0;
    let m = sc.cr.len();
    for i in 0..m {
        let (ki, entry) = sc.cr[i];
        let kn = sc.cr[(i + 1) % m].0;
        let seg = match (entry, join_outside) {
            (true, false) => (ki, kn),
            (false, true) => (kn, ki),
            _ => continue,
        };
        sc.segs.push(if flip { (seg.1, seg.0) } else { seg });
    }
}
