//! Stage 4 (ALGORITHM.md §3.6): splat each sample's normal into the vector field V, the
//! coefficients of the degree-2 B-splines of the octree's nodes, and measure the samples'
//! mean area weight Ā that scales the screening.

use rayon::prelude::*;

use super::density::Sampled;
use super::tree::Refined;
use crate::density::{cell_of, for_each_quadratic_neighbour};
use crate::octree::{DEPTH_OFFSET, NONE};
use crate::shared_slice::{written_zeros, SharedSlice};
use crate::{Error, Params, Result};

/// The output of [`splat`]: V, and the samples as the screening sees them.
#[derive(Debug, Clone)]
pub struct VectorField {
    /// V's coefficients per tree level and node (empty above the base level).
    pub v: Vec<Vec<[f32; 3]>>,
    /// The samples' weighted mean area weight Ā.
    pub mean_area: f64,
    /// The samples' weighted mean estimated depth.
    pub mean_depth: f64,
    /// The samples' total weight, over which the means are taken.
    pub weight: f64,
}

/// Splats the samples' normals into V (stage 4).
///
/// Each node must receive its terms in the order of the samples, as one loop over them would
/// add them (V is summed in `f32`, so the order sets the bits). The levels' cells are split
/// into slabs along z, and each slab, in parallel, adds in sample order the terms that land in
/// its own cells ([`splat_slab`]); a sample next to a slab's edge is visited by both slabs it
/// reaches. So the result is the same for any thread count, and the same as the serial loop.
pub fn splat(refined: &Refined, sampled: &Sampled, params: &Params) -> Result<VectorField> {
    let tree = &refined.tree;
    let base = params.base_depth().max(1).min(params.depth);
    let tb = (base + DEPTH_OFFSET) as usize;
    let mut v: Vec<Vec<[f32; 3]>> = (0..tree.levels.len())
        .map(|t| {
            if t >= tb {
                // Written now, by all threads, stretch by stretch (`written_zeros`). Left to
                // the slabs, whose first touches are scattered over each level by every
                // thread, the page faults took longer than the splatting: on 2 threads the
                // stage was 1.7 times slower than on 1 (bunny_1m, depth 10).
                written_zeros(tree.levels[t].len())
            } else {
                Vec::new()
            }
        })
        .collect();
    let (mut sum_wa, mut sum_w, mut sum_depth) = (0.0, 0.0, 0.0);
    let per_sample = sampled.samples.iter().zip(&refined.splats);
    for ((s, sp), q) in per_sample.zip(&sampled.depths) {
        if sp.is_some() {
            sum_wa += s.weight * q.area;
            sum_w += s.weight;
            sum_depth += s.weight * q.depth;
        }
    }
    if sum_w <= 0.0 {
        return Err(Error::Degenerate(
            "the normals cancel everywhere (opposite normals at the same places)".into(),
        ));
    }
    add_splats(refined, sampled, &mut v, CHUNK);
    Ok(VectorField {
        v,
        mean_area: sum_wa / sum_w,
        mean_depth: sum_depth / sum_w,
        weight: sum_w,
    })
}

/// Adds every sample's splats to `v`, slab by slab in parallel (see [`splat`]); `chunk`
/// samples at a time are sorted into the slabs.
fn add_splats(refined: &Refined, sampled: &Sampled, v: &mut [Vec<[f32; 3]>], chunk: usize) {
    let slabs = slab_lists(refined, sampled, chunk);
    let shared: Vec<SharedSlice<[f32; 3]>> = v.iter_mut().map(|l| SharedSlice::new(l)).collect();
    slabs.par_iter().for_each(|slab| {
        // SAFETY: a slab writes only the nodes of its own cells (`splat_slab`), and the slabs
        // of a level hold disjoint rows of cells, so no two tasks write the same node.
        unsafe { splat_slab(slab, refined, sampled, &shared[slab.level as usize]) }
    });
}

/// Slabs per thread and level: enough for the threads to share the work evenly.
const SLABS_PER_THREAD: i64 = 4;
/// Fewest rows per slab: a splat next to a slab's edge is visited twice, so thin slabs cost.
const MIN_ROWS: i64 = 16;
/// Samples per chunk when the slabs' lists are built.
const CHUNK: usize = 1 << 16;

/// One slab of a level's cells, the rows `z0..z1` along z, and the samples' splats that reach
/// it: `(sample << 1) | entry` of `Splat::levels`, in sample order.
struct Slab {
    level: u32,
    z0: i64,
    z1: i64,
    entries: Vec<u64>,
}

/// The slabs of every level that has splats, each with the splats that reach it. Built in
/// chunks of `chunk` samples in parallel, each chunk's lists joined in chunk order, so that
/// every slab's list keeps the sample order.
fn slab_lists(refined: &Refined, sampled: &Sampled, chunk: usize) -> Vec<Slab> {
    let nlev = refined.tree.levels.len();
    let rows = |t: usize| 1i64 << (t as u32).saturating_sub(DEPTH_OFFSET);
    // The slab count changes only who adds which terms, not their order, so it may depend on
    // the threads.
    let slabs = SLABS_PER_THREAD * rayon::current_num_threads() as i64;
    let per_level = |t: usize| slabs.min(rows(t) / MIN_ROWS).max(1) as usize;
    let first: Vec<usize> = (0..=nlev)
        .scan(0, |acc, t| {
            let f = *acc;
            *acc += if t < nlev { per_level(t) } else { 0 };
            Some(f)
        })
        .collect();
    let chunks: Vec<Vec<Vec<u64>>> = refined
        .splats
        .par_chunks(chunk)
        .enumerate()
        .map(|(k, splats)| {
            let mut lists = vec![Vec::new(); first[nlev]];
            for (j, sp) in splats.iter().enumerate() {
                let Some(sp) = sp else { continue };
                let i = (k * chunk + j) as u64;
                for (e, &(d, f)) in sp.levels.iter().enumerate() {
                    if f <= 0.0 {
                        continue;
                    }
                    let t = (d + DEPTH_OFFSET) as usize;
                    let (n, per) = (rows(t), per_level(t) as i64);
                    let z = cell_of(sampled.samples[i as usize].pos, d)[2];
                    // The slabs of the rows z − 1 ..= z, which the splat reaches.
                    let lo = ((z - 1).max(0) * per / n) as usize;
                    let hi = ((z + 1).min(n - 1) * per / n) as usize;
                    for slab in lo..=hi {
                        lists[first[t] + slab].push((i << 1) | e as u64);
                    }
                }
            }
            lists
        })
        .collect();
    (0..nlev)
        .flat_map(|t| (0..per_level(t)).map(move |slab| (t, slab)))
        .collect::<Vec<_>>()
        .into_par_iter()
        .map(|(t, slab)| {
            let (n, per) = (rows(t), per_level(t) as i64);
            let k = first[t] + slab;
            Slab {
                level: t as u32,
                z0: (slab as u64 * n as u64).div_ceil(per as u64) as i64,
                z1: ((slab as u64 + 1) * n as u64).div_ceil(per as u64) as i64,
                entries: chunks.iter().flat_map(|c| c[k].iter().copied()).collect(),
            }
        })
        .filter(|s| !s.entries.is_empty())
        .collect()
}

/// Adds to `v` (the slab's level) the terms of the slab's splats that land in its rows, in
/// the order of its list.
///
/// # Safety
/// No other thread writes the nodes of the slab's rows meanwhile.
unsafe fn splat_slab(slab: &Slab, refined: &Refined, sampled: &Sampled, v: &SharedSlice<[f32; 3]>) {
    let tree = &refined.tree;
    let t = slab.level;
    let d = t - DEPTH_OFFSET;
    let h = 1.0 / (1i64 << d) as f64;
    let n = 1u64 << d;
    for &entry in &slab.entries {
        let i = (entry >> 1) as usize;
        let (s, q) = (&sampled.samples[i], &sampled.depths[i]);
        let Some(sp) = &refined.splats[i] else {
            continue;
        };
        let f = sp.levels[(entry & 1) as usize].1;
        let c = cell_of(s.pos, d);
        let key = [c[0] as u64 + n, c[1] as u64 + n, c[2] as u64 + n];
        let (tt, node) = tree.descend(key, t, t);
        debug_assert_eq!(tt, t);
        let scale = -s.weight * q.area / (h * h * h) * f;
        let rel: [f64; 3] = std::array::from_fn(|a| (s.pos[a] / h - c[a] as f64).clamp(0.0, 1.0));
        for_each_quadratic_neighbour(rel, |o, wt| {
            if !(slab.z0..slab.z1).contains(&(c[2] + o[2])) {
                return;
            }
            let m = tree.neighbor(t, node, o);
            if m == NONE {
                return;
            }
            let w = scale * wt;
            let m = m as usize;
            let mut cell = v.get(m);
            for a in 0..3 {
                cell[a] += (w * s.normal[a]) as f32;
            }
            v.set(m, cell);
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pipeline::{density, prepare, tests::sphere, tree};

    /// V as one loop over the samples would add it: a single slab per level, holding every
    /// row and every splat in sample order.
    fn serial(refined: &Refined, sampled: &Sampled, v: &mut [Vec<[f32; 3]>]) {
        for (t, level) in v.iter_mut().enumerate() {
            let entries: Vec<u64> = refined
                .splats
                .iter()
                .enumerate()
                .filter_map(|(i, sp)| sp.as_ref().map(|sp| (i, sp)))
                .flat_map(|(i, sp)| {
                    let here = sp.levels.iter().enumerate();
                    here.filter(move |(_, &(d, f))| d + DEPTH_OFFSET == t as u32 && f > 0.0)
                        .map(move |(e, _)| ((i as u64) << 1) | e as u64)
                })
                .collect();
            if entries.is_empty() {
                continue;
            }
            let rows = 1i64 << (t as u32 - DEPTH_OFFSET);
            let slab = Slab {
                level: t as u32,
                z0: 0,
                z1: rows,
                entries,
            };
            // SAFETY: one thread writes.
            unsafe { splat_slab(&slab, refined, sampled, &SharedSlice::new(level)) };
        }
    }

    /// The slabs give every node the serial loop's sum to the last bit, for one splat depth
    /// per sample and for two, on 1 and 3 threads.
    #[test]
    fn the_slabs_add_each_nodes_terms_in_sample_order() {
        for two_level_splat in [false, true] {
            let params = Params {
                depth: 8,
                two_level_splat,
                ..Params::default()
            };
            let cloud = sphere(40_000, [0.45, 0.5, 0.55], 0.3);
            let prepared = prepare::prepare(&cloud, &params).unwrap();
            let sampled = density::sample(prepared.points, prepared.carried, &params);
            let refined = tree::build(&sampled, &params, cloud.positions.len()).unwrap();
            let mut want: Vec<Vec<[f32; 3]>> = splat(&refined, &sampled, &params).unwrap().v;
            want.iter_mut().for_each(|l| l.fill([0.0; 3]));
            let mut got = want.clone();
            serial(&refined, &sampled, &mut want);
            assert!(want.iter().flatten().any(|c| c[0] != 0.0));
            let bits = |v: &[Vec<[f32; 3]>]| -> Vec<u32> {
                v.iter().flatten().flatten().map(|x| x.to_bits()).collect()
            };
            for (threads, chunk) in [(1, CHUNK), (3, CHUNK), (3, 1000)] {
                got.iter_mut().for_each(|l| l.fill([0.0; 3]));
                let pool = rayon::ThreadPoolBuilder::new()
                    .num_threads(threads)
                    .build()
                    .unwrap();
                pool.install(|| add_splats(&refined, &sampled, &mut got, chunk));
                assert!(
                    bits(&got) == bits(&want),
                    "two-level {two_level_splat}, {threads} threads, chunks of {chunk}"
                );
            }
        }
    }
}
