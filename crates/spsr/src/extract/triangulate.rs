//! Polygons to triangles: the segments of a leaf are chained into closed loops, and each loop
//! is fanned around its barycentre or given its minimum-area triangulation.

use super::blocks::{ChunkOut, Ctx, Scratch};
use super::vertex::{crossing_point, owns, unit_f32, Crossing};
use super::{Cells, BARY};

/// Largest polygon triangulated by dynamic programming; larger ones are fanned.
const MAX_DP: usize = 16;

/// Chains the segments of a leaf into loops and triangulates them.
pub(super) fn finish_leaf<C: Cells>(
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
    sc.segs.sort_unstable();
    if sc.segs.windows(2).any(|w| w[0].0 == w[1].0) {
        sc.bad = true;
        return;
    }
    sc.used.clear();
    sc.used.resize(sc.segs.len(), false);
    for start in 0..sc.segs.len() {
        if sc.used[start] {
            continue;
        }
        sc.poly.clear();
        let mut cur = start;
        loop {
            sc.used[cur] = true;
            let (from, to) = sc.segs[cur];
            match sc.cross.binary_search_by_key(&from, |c| c.key) {
                Ok(i) => sc.poly.push(i as u32),
                Err(_) => {
                    sc.bad = true;
                    return;
                }
            }
            match sc.segs.binary_search_by_key(&to, |s| s.0) {
                Ok(j) if j == start => break,
                Ok(j) if !sc.used[j] => cur = j,
                _ => {
                    sc.bad = true;
                    return;
                }
            }
        }
        if sc.poly.len() >= 3 {
            triangulate(sc, lo, s, out);
        }
    }
}

/// Bit mask of the leaf faces (2·axis + side) that the crossing lies on.
fn face_mask(c: &Crossing, lo: [u32; 3], s: u32) -> u32 {
    let mut m = 0;
    for (b, (&e, &l)) in c.lo.iter().zip(&lo).enumerate() {
        if b == c.axis as usize {
            continue;
        }
        if e == l {
            m |= 1 << (2 * b);
        } else if e == l + s {
            m |= 1 << (2 * b + 1);
        }
    }
    m
}

/// Triangulates the loop in `sc.poly` (indices into `sc.cross`).
#[allow(clippy::needless_range_loop)]
fn triangulate<H>(sc: &mut Scratch<H>, lo: [u32; 3], s: u32, out: &mut ChunkOut) {
    let poly = &sc.poly;
    let k = poly.len();
    let key = |i: usize| sc.cross[poly[i] as usize].key;
    if k == 3 {
        out.tris.push([key(0), key(1), key(2)]);
        return;
    }
    let mut fan = k > MAX_DP;
    if !fan {
        let mut masks = [0u32; MAX_DP];
        for (m, &p) in masks.iter_mut().zip(poly.iter()) {
            *m = face_mask(&sc.cross[p as usize], lo, s);
        }
        'outer: for i in 0..k {
            for j in i + 2..k {
                if i == 0 && j == k - 1 {
                    continue;
                }
                if masks[i] & masks[j] != 0 {
                    fan = true;
                    break 'outer;
                }
            }
        }
    }
    let pos = |i: usize| sc.pos[poly[i] as usize];
    if fan {
        let mut b = [0.0; 3];
        for i in 0..k {
            let p = pos(i);
            for a in 0..3 {
                b[a] += p[a];
            }
        }
        let b = b.map(|x| x / k as f64);
        let r = BARY | out.bary.len() as u64;
        out.bary.push(b);
        if !sc.nrm.is_empty() {
            let mut n = [0.0; 3];
            for i in 0..k {
                let v = sc.nrm[poly[i] as usize];
                for a in 0..3 {
                    n[a] += v[a];
                }
            }
            out.bary_nrm.push(unit_f32(n));
        }
        for i in 0..k {
            out.tris.push([r, key(i), key((i + 1) % k)]);
        }
        return;
    }
    // Minimum-area triangulation by dynamic programming over polygon intervals.
    let mut cost = [[0.0f64; MAX_DP]; MAX_DP];
    let mut split = [[0u8; MAX_DP]; MAX_DP];
    let mut pts = [[0.0f64; 3]; MAX_DP];
    for (i, p) in pts.iter_mut().enumerate().take(k) {
        *p = pos(i);
    }
    let area = |a: usize, b: usize, c: usize| {
        let (pa, pb, pc) = (pts[a], pts[b], pts[c]);
        let u = [pb[0] - pa[0], pb[1] - pa[1], pb[2] - pa[2]];
        let v = [pc[0] - pa[0], pc[1] - pa[1], pc[2] - pa[2]];
        let x = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt()
    };
    for gap in 2..k {
        for i in 0..k - gap {
            let j = i + gap;
            let mut best = f64::INFINITY;
            let mut bm = i + 1;
            for m in i + 1..j {
                let c = cost[i][m] + cost[m][j] + area(i, m, j);
                if c < best {
                    best = c;
                    bm = m;
                }
            }
            cost[i][j] = best;
            split[i][j] = bm as u8;
        }
    }
    let mut stack = [(0usize, 0usize); MAX_DP];
    let mut top = 1;
    stack[0] = (0, k - 1);
    while top > 0 {
        top -= 1;
        let (i, j) = stack[top];
        if j < i + 2 {
            continue;
        }
        let m = split[i][j] as usize;
        out.tris.push([key(i), key(m), key(j)]);
        stack[top] = (i, m);
        stack[top + 1] = (m, j);
        top += 2;
    }
}
