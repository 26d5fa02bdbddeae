//! Stage 4 (ALGORITHM.md §3.6): splat each sample's normal into the vector field V, the
//! coefficients of the degree-2 B-splines of the octree's nodes, and measure the samples'
//! mean area weight Ā that scales the screening.

use super::density::Sampled;
use super::tree::Refined;
use crate::density::{cell_of, for_each_quadratic_neighbour};
use crate::octree::{DEPTH_OFFSET, NONE};
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
pub fn splat(refined: &Refined, sampled: &Sampled, params: &Params) -> Result<VectorField> {
    let tree = &refined.tree;
    let base = params.base_depth().max(1).min(params.depth);
    let tb = (base + DEPTH_OFFSET) as usize;
    let mut v: Vec<Vec<[f32; 3]>> = (0..tree.levels.len())
        .map(|t| {
            if t >= tb {
                vec![[0.0; 3]; tree.levels[t].len()]
            } else {
                Vec::new()
            }
        })
        .collect();
    let mut sum_wa = 0.0;
    let mut sum_w = 0.0;
    let mut sum_depth = 0.0;
    let per_sample = sampled
        .samples
        .iter()
        .zip(&refined.splats)
        .zip(&sampled.depths);
    for ((s, sp), q) in per_sample {
        let Some(sp) = sp else { continue };
        sum_wa += s.weight * q.area;
        sum_w += s.weight;
        sum_depth += s.weight * q.depth;
        for &(d, f) in &sp.levels {
            if f <= 0.0 {
                continue;
            }
            let t = d + DEPTH_OFFSET;
            let h = 1.0 / (1i64 << d) as f64;
            let c = cell_of(s.pos, d);
            let n = 1u64 << d;
            let key = [c[0] as u64 + n, c[1] as u64 + n, c[2] as u64 + n];
            let (tt, node) = tree.descend(key, t, t);
            debug_assert_eq!(tt, t);
            let scale = -s.weight * q.area / (h * h * h) * f;
            let rel: [f64; 3] =
                std::array::from_fn(|a| (s.pos[a] / h - c[a] as f64).clamp(0.0, 1.0));
            for_each_quadratic_neighbour(rel, |o, wt| {
                let m = tree.neighbor(t, node, o);
                if m == NONE {
                    return;
                }
                let w = scale * wt;
                let cell = &mut v[t as usize][m as usize];
                for a in 0..3 {
                    cell[a] += (w * s.normal[a]) as f32;
                }
            });
        }
    }
    if sum_w <= 0.0 {
        return Err(Error::Degenerate(
            "the normals cancel everywhere (opposite normals at the same places)".into(),
        ));
    }
    Ok(VectorField {
        v,
        mean_area: sum_wa / sum_w,
        mean_depth: sum_depth / sum_w,
        weight: sum_w,
    })
}
