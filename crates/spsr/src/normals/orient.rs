//! Choosing the sign of each normal: towards viewpoints, by propagation along a minimum
//! spanning tree, and the global correction by a Poisson indicator function.

use rayon::prelude::*;

use super::graph::{spanning_forest, symmetric_edges, Forest};
use super::knn::{k_nearest, Neighbours, Tree};
use super::{dot, norm};

/// Sum of `f(i)` over `0..n` in a fixed order (chunks summed in parallel, then in sequence), so
/// that the result does not depend on the thread count.
pub(crate) fn det_sum(n: usize, f: impl Fn(usize) -> f64 + Sync) -> f64 {
    const CHUNK: usize = 4096;
    let parts: Vec<f64> = (0..n.div_ceil(CHUNK))
        .into_par_iter()
        .map(|c| (c * CHUNK..((c + 1) * CHUNK).min(n)).map(&f).sum())
        .collect();
    parts.iter().sum()
}

/// Flips the normals that point away from their sensor origin; returns how many flipped.
pub(crate) fn towards(
    positions: &[[f64; 3]],
    normals: &mut [[f64; 3]],
    origin_of: impl Fn(usize) -> [f64; 3] + Sync,
) -> usize {
    normals
        .par_iter_mut()
        .enumerate()
        .map(|(i, n)| {
            let p = positions[i];
            let o = origin_of(i);
            let v = [o[0] - p[0], o[1] - p[1], o[2] - p[2]];
            if dot(*n, v) < 0.0 {
                *n = n.map(|c| -c);
                1
            } else {
                0
            }
        })
        .sum()
}

/// The neighbour graph of the points that have a normal, with everything the weights need.
pub(crate) struct Graph {
    /// Points that take part (finite position, non-zero finite normal), increasing.
    pub usable: Vec<u32>,
    pub nb: Neighbours,
    /// Undirected edges `(i, j)`, `i < j`, in cloud indices.
    pub edges: Vec<(u32, u32)>,
    /// How far each point's neighbours stray from its tangent plane (median of
    /// `|(p_j − p_i) · n_i|`): the local noise level.
    pub spread: Vec<f64>,
}

pub(crate) fn usable_points(positions: &[[f64; 3]], normals: &[[f64; 3]]) -> Vec<u32> {
    (0..positions.len() as u32)
        .filter(|&i| {
            let (p, n) = (positions[i as usize], normals[i as usize]);
            let l = norm(n);
            p.iter().all(|c| c.is_finite()) && l > 0.0 && l.is_finite()
        })
        .collect()
}

impl Graph {
    pub fn new(positions: &[[f64; 3]], normals: &[[f64; 3]], k: usize) -> Self {
        let usable = usable_points(positions, normals);
        let tree = Tree::new(positions, usable.clone());
        let mut nb = k_nearest(positions, &tree, k);
        // Points without a usable normal keep no neighbours.
        let mut is_usable = vec![false; positions.len()];
        for &i in &usable {
            is_usable[i as usize] = true;
        }
        nb.idx
            .par_chunks_mut(k.max(1))
            .enumerate()
            .for_each(|(i, s)| {
                if !is_usable[i] {
                    s.fill(super::knn::NONE);
                }
            });
        let edges = symmetric_edges(&nb);
        let spread = (0..positions.len())
            .into_par_iter()
            .map_init(Vec::new, |buf: &mut Vec<f64>, i| {
                buf.clear();
                let (p, n) = (positions[i], unit(normals[i]));
                buf.extend(nb.of(i).map(|j| {
                    let q = positions[j];
                    dot([q[0] - p[0], q[1] - p[1], q[2] - p[2]], n).abs()
                }));
                if buf.is_empty() {
                    return 0.0;
                }
                let m = buf.len() / 2;
                *buf.select_nth_unstable_by(m, f64::total_cmp).1
            })
            .collect();
        Self {
            usable,
            nb,
            edges,
            spread,
        }
    }
}

pub(crate) fn unit(n: [f64; 3]) -> [f64; 3] {
    let l = norm(n);
    if l > 0.0 {
        n.map(|c| c / l)
    } else {
        n
    }
}

/// How consistently oriented two unit normals are, in `[-1, 1]`: 1 when `n_j` is what
/// `n_i` becomes when carried along the shortest smooth curve from `p_i` to `p_j`, −1 when it
/// is the opposite.
///
/// On a circular arc through both points the two normals are mirror images in the plane that
/// bisects the chord, so `n_j` is compared with `n_i` after reflection in that plane. This
/// keeps its sign right where the normals turn sharply between the points: across creases and
/// around the rim of a thin plate, where the plain `n_i · n_j` is near 0 or wrong. The part of
/// the chord along the normals that is within `noise` is not trusted (noise would make the
/// reflection random), and is removed first; with all of it removed the measure is `n_i · n_j`.
pub(crate) fn consistency(
    pi: [f64; 3],
    ni: [f64; 3],
    pj: [f64; 3],
    nj: [f64; 3],
    noise: f64,
) -> f64 {
    let mut d = [pj[0] - pi[0], pj[1] - pi[1], pj[2] - pi[2]];
    // Mean normal line of the two points.
    let s = if dot(ni, nj) >= 0.0 { 1.0 } else { -1.0 };
    let m = unit([ni[0] + s * nj[0], ni[1] + s * nj[1], ni[2] + s * nj[2]]);
    let dn = dot(d, m);
    let kept = dn.signum() * (dn.abs() - noise).max(0.0);
    for a in 0..3 {
        d[a] += (kept - dn) * m[a];
    }
    let l = norm(d);
    if !(l > 0.0) {
        return dot(ni, nj).clamp(-1.0, 1.0);
    }
    let e = d.map(|c| c / l);
    let ne = dot(nj, e);
    let r = [
        nj[0] - 2.0 * ne * e[0],
        nj[1] - 2.0 * ne * e[1],
        nj[2] - 2.0 * ne * e[2],
    ];
    dot(ni, r).clamp(-1.0, 1.0)
}

/// Multiple of the local spread of the points across their tangent planes that is treated as
/// noise in [`consistency`].
const NOISE_SPREADS: f64 = 2.0;

/// The result of [`propagate`].
pub(crate) struct Propagation {
    /// Component of each point (`u32::MAX` for points without a usable normal), numbered in
    /// order of their smallest point.
    pub component: Vec<u32>,
    pub components: usize,
    /// The spanning forest.
    pub forest: Forest,
    /// Weight of each edge of `graph.edges`.
    pub weights: Vec<f64>,
}

/// Orients the normals consistently within each connected component of the neighbour graph,
/// by a traversal of the minimum spanning forest under the weights `1 − |consistency|`
/// (Hoppe et al. 1992 used `1 − |n_i · n_j|`). Returns the components.
pub(crate) fn propagate(
    positions: &[[f64; 3]],
    normals: &mut [[f64; 3]],
    graph: &Graph,
) -> Propagation {
    let n = positions.len();
    let units: Vec<[f64; 3]> = normals.par_iter().map(|&v| unit(v)).collect();
    let weights: Vec<f64> = graph
        .edges
        .par_iter()
        .map(|&(i, j)| {
            let (i, j) = (i as usize, j as usize);
            let noise = NOISE_SPREADS * graph.spread[i].max(graph.spread[j]);
            1.0 - consistency(positions[i], units[i], positions[j], units[j], noise).abs()
        })
        .collect();
    let chosen = spanning_forest(n, &graph.edges, &weights);
    let forest = Forest::new(n, &graph.edges, &chosen);
    drop(chosen);
    let mut component = vec![u32::MAX; n];
    let mut components = 0u32;
    let mut queue = std::collections::VecDeque::new();
    for &root in &graph.usable {
        if component[root as usize] != u32::MAX {
            continue;
        }
        component[root as usize] = components;
        queue.push_back(root);
        while let Some(u) = queue.pop_front() {
            let u = u as usize;
            for &v in forest.of(u) {
                let v = v as usize;
                if component[v] != u32::MAX {
                    continue;
                }
                component[v] = components;
                let noise = NOISE_SPREADS * graph.spread[u].max(graph.spread[v]);
                let c = consistency(
                    positions[u],
                    unit(normals[u]),
                    positions[v],
                    units[v],
                    noise,
                );
                if c < 0.0 {
                    normals[v] = normals[v].map(|x| -x);
                }
                queue.push_back(v as u32);
            }
        }
        components += 1;
    }
    Propagation {
        component,
        components: components as usize,
        forest,
        weights,
    }
}

/// Flips whole components so that their normals point outward: a closed surface oriented
/// outward has `Σ a_i (p_i − g) · n_i = 3 × volume > 0` for any point g (the divergence
/// theorem, with `a_i` the area each point stands for, here the square of its neighbourhood
/// radius); g is the centroid of all points, which also serves open pieces of a larger
/// surface. Returns the number of normals flipped.
pub(crate) fn outward(
    positions: &[[f64; 3]],
    normals: &mut [[f64; 3]],
    graph: &Graph,
    component: &[u32],
    components: usize,
) -> usize {
    let m = graph.usable.len();
    if m == 0 {
        return 0;
    }
    let u = &graph.usable;
    let g: [f64; 3] =
        std::array::from_fn(|a| det_sum(m, |k| positions[u[k] as usize][a]) / m as f64);
    let terms: Vec<f64> = u
        .par_iter()
        .map(|&i| {
            let (p, n) = (positions[i as usize], unit(normals[i as usize]));
            let r = graph.nb.radius[i as usize];
            r * r * dot([p[0] - g[0], p[1] - g[1], p[2] - g[2]], n)
        })
        .collect();
    let mut vote = vec![0.0; components];
    for (&i, t) in u.iter().zip(&terms) {
        vote[component[i as usize] as usize] += t;
    }
    let mut flipped = 0;
    for &i in u {
        if vote[component[i as usize] as usize] < 0.0 {
            normals[i as usize] = normals[i as usize].map(|x| -x);
            flipped += 1;
        }
    }
    flipped
}

/// The global correction (placeholder).
pub(crate) fn correct(
    _positions: &[[f64; 3]],
    _normals: &mut [[f64; 3]],
    _graph: &Graph,
    _prop: &Propagation,
    _depth: u32,
    _rounds: u32,
) -> crate::Result<Vec<usize>> {
    Ok(Vec::new())
}
