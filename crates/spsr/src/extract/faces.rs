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
            // `r` is the offset plus one, wrapped: below 3 iff the offset is in -1..=1.
            let r: [u32; 3] =
                std::array::from_fn(|a| offset[a].wrapping_sub(self.offset[a]).wrapping_add(1));
            if r.iter().all(|&x| x < 3) {
                return self.around >> (r[0] + 3 * r[1] + 9 * r[2]) & 1 != 0;
            }
        }
        cells.refined(self.h, depth, offset)
    }
}

/// Depth of the cells of width `size` (in finest-cell units).
#[inline]
fn depth_of(ctx_max: u32, size: u32) -> u32 {
    ctx_max - size.trailing_zeros()
}

/// A square of a leaf face: `origin + [0,size]²` in the plane normal to axis `n`; the leaf
/// lies above it when `flip`, below otherwise.
#[derive(Clone, Copy)]
struct Square {
    origin: [u32; 3],
    size: u32,
    n: usize,
    flip: bool,
}

impl Square {
    /// The in-plane axes `(u, v)`, so that `(u, v, n)` is a cyclic order of the axes.
    #[inline]
    fn axes(&self) -> (usize, usize) {
        ((self.n + 1) % 3, (self.n + 2) % 3)
    }
}

/// A dyadic segment: from `a`, `len` long along `axis`, towards + when `forward`.
#[derive(Clone, Copy)]
struct Side {
    a: [u32; 3],
    axis: usize,
    forward: bool,
    len: u32,
}

/// The walk over one leaf's boundary: the shared state, and the leaf.
struct Walk<'a, C: Cells> {
    ctx: &'a Ctx<'a, C>,
    here: Here<C::Handle>,
}

/// Visits the six faces of the leaf at `lo` (size `s`) whose corners have the cache indices
/// `cidx` (bit `a` of the corner number set for the far side along axis `a`), appending the
/// leaf's crossings and oriented segments.
pub(super) fn leaf_faces<C: Cells>(
    ctx: &Ctx<C>,
    sc: &mut Scratch<C::Handle>,
    here: Here<C::Handle>,
    lo: [u32; 3],
    s: u32,
    cidx: &[u32; 8],
) {
    let walk = Walk { ctx, here };
    for n in 0..3 {
        let (u, v) = ((n + 1) % 3, (n + 2) % 3);
        for side in 0..2u32 {
            let mut origin = lo;
            origin[n] += side * s;
            let c0 = (side as usize) << n;
            let known = [
                cidx[c0],
                cidx[c0 | 1 << u],
                cidx[c0 | 1 << u | 1 << v],
                cidx[c0 | 1 << v],
            ];
            let square = Square {
                origin,
                size: s,
                n,
                flip: side == 0,
            };
            walk.face(sc, square, Some(known));
        }
    }
}

/// Whether every leaf corner on the boundary of the leaf `here` at `lo` (size `s`) is on the
/// side `inside` of the iso-surface, as all eight of its own corners are: then none of its face
/// pieces has a crossing, and the walk can be skipped. The corners looked at are those of the
/// leaves in the refined same-depth cells around the leaf that touch its closure, which
/// include every corner the walk would split a piece's side at; corners only on the leaf's
/// own depth grid are its eight corners.
pub(super) fn boundary_uniform<C: Cells>(
    ctx: &Ctx<C>,
    sc: &mut Scratch<C::Handle>,
    here: Here<C::Handle>,
    lo: [u32; 3],
    s: u32,
    inside: bool,
) -> bool {
    let n = 1u32 << here.depth;
    (0..27u32).filter(|&b| here.around >> b & 1 != 0).all(|b| {
        let cell: [Option<u32>; 3] = std::array::from_fn(|a| {
            (here.offset[a] + (b / 3u32.pow(a as u32)) % 3)
                .checked_sub(1)
                .filter(|&c| c < n)
        });
        // Cells outside the unit cube are not extracted (the walk never splits at them).
        match cell {
            [Some(x), Some(y), Some(z)] => {
                subtree_uniform(ctx, sc, here, (here.depth, [x, y, z]), lo, s, inside)
            }
            _ => true,
        }
    })
}

/// [`boundary_uniform`] within the refined cell `(depth, offset)`: its children that touch
/// the closed box `lo ..= lo + s`, their leaves' corners in the box.
fn subtree_uniform<C: Cells>(
    ctx: &Ctx<C>,
    sc: &mut Scratch<C::Handle>,
    here: Here<C::Handle>,
    (depth, offset): (u32, [u32; 3]),
    lo: [u32; 3],
    s: u32,
    inside: bool,
) -> bool {
    let size = 1u32 << (ctx.max_depth - depth - 1);
    let in_box = |c: [u32; 3]| (0..3).all(|a| (lo[a]..=lo[a] + s).contains(&c[a]));
    (0..8u32).all(|k| {
        let child: [u32; 3] = std::array::from_fn(|a| 2 * offset[a] + (k >> a & 1));
        let clo = child.map(|x| x * size);
        if (0..3).any(|a| clo[a] + size < lo[a] || clo[a] > lo[a] + s) {
            return true;
        }
        if here.refined(ctx.cells, depth + 1, child) {
            return subtree_uniform(ctx, sc, here, (depth + 1, child), lo, s, inside);
        }
        (0..8u32).all(|c| {
            let p: [u32; 3] = std::array::from_fn(|a| clo[a] + size * (c >> a & 1));
            if !in_box(p) {
                return true;
            }
            let i = sc.corners.get(ctx, p, here.h);
            (sc.corners.d[i as usize] > 0.0) == inside
        })
    })
}

impl<C: Cells> Walk<'_, C> {
    /// Visits the pieces tiling the square `sq` of a leaf face. `known` holds the cache indices of
    /// the square's corners (counter-clockwise around +n from the origin) when the caller has them.
    fn face(&self, sc: &mut Scratch<C::Handle>, sq: Square, known: Option<[u32; 4]>) {
        let Square {
            origin, size, n, ..
        } = sq;
        let (u, v) = sq.axes();
        if size > 1 {
            // The square is subdivided iff the cell of its size across it is refined.
            let k = depth_of(self.ctx.max_depth, size);
            let across = if sq.flip {
                origin[n].checked_sub(size)
            } else {
                (origin[n] < self.ctx.full).then_some(origin[n])
            };
            if let Some(a) = across {
                // Sizes are powers of two: shifts, not divisions (which showed in profiles).
                let sh = size.trailing_zeros();
                let mut cell = origin.map(|x| x >> sh);
                cell[n] = a >> sh;
                if self.here.refined(self.ctx.cells, k, cell) {
                    let half = size / 2;
                    for (du, dv) in [(0, 0), (1, 0), (1, 1), (0, 1)] {
                        let mut o = origin;
                        o[u] += du * half;
                        o[v] += dv * half;
                        let quarter = Square {
                            origin: o,
                            size: half,
                            ..sq
                        };
                        self.face(sc, quarter, None);
                    }
                    return;
                }
            }
        }
        self.piece(sc, sq, known);
    }

    /// Whether the midpoint of the dyadic segment `side` is a leaf corner: iff one of the four
    /// cells of size `len` around the segment is refined.
    fn segment_split(&self, side: Side) -> bool {
        let Side {
            a,
            axis,
            forward,
            len,
        } = side;
        let k = depth_of(self.ctx.max_depth, len);
        let mut e = a;
        if !forward {
            e[axis] -= len;
        }
        let (u, v) = ((axis + 1) % 3, (axis + 2) % 3);
        // `len` is a power of two: shifts, not divisions (this loop is hot).
        let sh = len.trailing_zeros();
        let cell_count = self.ctx.full >> sh;
        for du in 0..2u32 {
            for dv in 0..2u32 {
                let (Some(cu), Some(cv)) =
                    ((e[u] >> sh).checked_sub(du), (e[v] >> sh).checked_sub(dv))
                else {
                    continue;
                };
                if cu >= cell_count || cv >= cell_count {
                    continue;
                }
                let mut cell = [0u32; 3];
                cell[axis] = e[axis] >> sh;
                cell[u] = cu;
                cell[v] = cv;
                if self.here.refined(self.ctx.cells, k, cell) {
                    return true;
                }
            }
        }
        false
    }

    /// Pushes the leaf corners strictly inside the dyadic segment `side`, in order from its start.
    /// A leaf with no refined cell of its own depth around it (`around == 0`) has no such
    /// corners: its faces are not subdivided, and the cells around its own sides are of its
    /// depth, all among those `around` covers.
    fn split_side(&self, sc: &mut Scratch<C::Handle>, side: Side) {
        if side.len <= 1 || self.here.around == 0 || !self.segment_split(side) {
            return;
        }
        let half = side.len / 2;
        let mut m = side.a;
        if side.forward {
            m[side.axis] += half;
        } else {
            m[side.axis] -= half;
        }
        self.split_side(sc, Side { len: half, ..side });
        let i = sc.corners.get(self.ctx, m, self.here.h);
        sc.bv.push((m, i));
        self.split_side(
            sc,
            Side {
                a: m,
                len: half,
                ..side
            },
        );
    }

    /// Marching squares on one face piece; appends its oriented segments and crossings.
    fn piece(&self, sc: &mut Scratch<C::Handle>, sq: Square, known: Option<[u32; 4]>) {
        let idx = self.piece_boundary(sc, sq, known);
        let d = &sc.corners.d;
        let first = d[sc.bv[0].1 as usize] > 0.0;
        if sc.bv.iter().all(|b| (d[b.1 as usize] > 0.0) == first) {
            return;
        }
        piece_crossings(sc);
        // Pairing rule (see module docs).
        let d = &sc.corners.d;
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
            sc.segs.push(if sq.flip { (seg.1, seg.0) } else { seg });
        }
    }

    /// Fills `sc.bv` with the boundary of the piece `sq`, counter-clockwise around +n: its four
    /// corners and the leaf corners on its sides. Returns the cache indices of the four corners.
    fn piece_boundary(
        &self,
        sc: &mut Scratch<C::Handle>,
        sq: Square,
        known: Option<[u32; 4]>,
    ) -> [u32; 4] {
        let (u, v) = sq.axes();
        let size = sq.size;
        let mut p = [sq.origin; 4];
        p[1][u] += size;
        p[2][u] += size;
        p[2][v] += size;
        p[3][v] += size;
        let idx = match known {
            Some(k) => k,
            None => p.map(|c| sc.corners.get(self.ctx, c, self.here.h)),
        };
        sc.bv.clear();
        let sides = [(u, true), (v, true), (u, false), (v, false)];
        for (c, &(axis, forward)) in sides.iter().enumerate() {
            sc.bv.push((p[c], idx[c]));
            let side = Side {
                a: p[c],
                axis,
                forward,
                len: size,
            };
            self.split_side(sc, side);
        }
        idx
    }
}

/// Records the sign changes along the boundary in `sc.bv`: in `sc.cr` (edge key, and whether
/// the crossing enters the inside), in boundary order, and in `sc.cross`.
fn piece_crossings<H>(sc: &mut Scratch<H>) {
    let d = &sc.corners.d;
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
}
