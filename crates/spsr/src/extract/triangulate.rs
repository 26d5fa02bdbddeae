//! Polygons to triangles: the segments of a leaf are chained into closed loops, and each loop
//! is fanned around its barycentre or given its minimum-area triangulation.

use super::blocks::{ChunkOut, Scratch};
use super::vertex::{unit_f32, Crossing};
use super::BARY;
use crate::vec3::{add, cross, norm, sub};

/// Largest polygon triangulated by dynamic programming; larger ones are fanned.
const MAX_DP: usize = 16;

/// Chains the segments of the leaf at `lo` (size `s`) into loops and triangulates them;
/// `sc.cross` must be sorted by key. Sets `sc.bad` when the segments do not form closed loops
/// (the leaves do not tile the cube).
pub(super) fn triangulate_loops<H>(sc: &mut Scratch<H>, lo: [u32; 3], s: u32, out: &mut ChunkOut) {
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
        if !chain_loop(sc, start) {
            sc.bad = true;
            return;
        }
        if sc.poly.len() >= 3 {
            triangulate(sc, lo, s, out);
        }
    }
}

/// Follows the segments from `sc.segs[start]` (sorted) round to it again, marking them used
/// and putting the loop's crossings (indices into `sc.cross`) in `sc.poly`. False when the
/// chain is broken.
fn chain_loop<H>(sc: &mut Scratch<H>, start: usize) -> bool {
    sc.poly.clear();
    let mut cur = start;
    loop {
        sc.used[cur] = true;
        let (from, to) = sc.segs[cur];
        match sc.cross.binary_search_by_key(&from, |c| c.key) {
            Ok(i) => sc.poly.push(i as u32),
            Err(_) => return false,
        }
        match sc.segs.binary_search_by_key(&to, |s| s.0) {
            Ok(j) if j == start => return true,
            Ok(j) if !sc.used[j] => cur = j,
            _ => return false,
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
fn triangulate<H>(sc: &Scratch<H>, lo: [u32; 3], s: u32, out: &mut ChunkOut) {
    let poly = &sc.poly;
    let key = |i: usize| sc.cross[poly[i] as usize].key;
    if poly.len() == 3 {
        out.tris.push([key(0), key(1), key(2)]);
    } else if poly.len() > MAX_DP || touches_a_face_twice(sc, lo, s) {
        fan(sc, out);
    } else {
        min_area(sc, out);
    }
}

/// Whether two non-consecutive vertices of the loop lie on a common face of the leaf (manifold
/// mode: a diagonal between them would run inside that face, which the leaf shares with its
/// neighbour).
fn touches_a_face_twice<H>(sc: &Scratch<H>, lo: [u32; 3], s: u32) -> bool {
    let poly = &sc.poly;
    let k = poly.len();
    let mut masks = [0u32; MAX_DP];
    for (m, &p) in masks.iter_mut().zip(poly.iter()) {
        *m = face_mask(&sc.cross[p as usize], lo, s);
    }
    for i in 0..k {
        for j in i + 2..k {
            if i == 0 && j == k - 1 {
                continue;
            }
            if masks[i] & masks[j] != 0 {
                return true;
            }
        }
    }
    false
}

/// Fans the loop in `sc.poly` around a new vertex at its barycentre.
fn fan<H>(sc: &Scratch<H>, out: &mut ChunkOut) {
    let poly = &sc.poly;
    let k = poly.len();
    let key = |i: usize| sc.cross[poly[i] as usize].key;
    let mut b = [0.0; 3];
    for &p in poly {
        b = add(b, sc.pos[p as usize]);
    }
    let b = b.map(|x| x / k as f64);
    let r = BARY | out.bary.len() as u64;
    out.bary.push(b);
    if !sc.nrm.is_empty() {
        let mut n = [0.0; 3];
        for &p in poly {
            n = add(n, sc.nrm[p as usize]);
        }
        out.bary_nrm.push(unit_f32(n));
    }
    for i in 0..k {
        out.tris.push([r, key(i), key((i + 1) % k)]);
    }
}

/// Minimum-area triangulation of the loop in `sc.poly` (at most [`MAX_DP`] vertices) by
/// dynamic programming over polygon intervals.
fn min_area<H>(sc: &Scratch<H>, out: &mut ChunkOut) {
    let poly = &sc.poly;
    let k = poly.len();
    let key = |i: usize| sc.cross[poly[i] as usize].key;
    let mut cost = [[0.0f64; MAX_DP]; MAX_DP];
    let mut split = [[0u8; MAX_DP]; MAX_DP];
    let mut pts = [[0.0f64; 3]; MAX_DP];
    for (p, &i) in pts.iter_mut().zip(poly.iter()) {
        *p = sc.pos[i as usize];
    }
    let area = |a: usize, b: usize, c: usize| {
        let (pa, pb, pc) = (pts[a], pts[b], pts[c]);
        norm(cross(sub(pb, pa), sub(pc, pa)))
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
