//! The relaxation of one level on the GPU (`crate::gpu`): the level's system laid out for
//! the kernel, and the order of [`Op::gauss_seidel_cpu`] as classes of independent nodes.

use rayon::prelude::*;

use super::Op;
use crate::gpu::{Device, LevelSystem};

impl Op<'_> {
    /// [`Op::gauss_seidel_cpu`] on `dev`, with the same result to the last bit.
    pub(super) fn gauss_seidel_gpu<R: Copy + Into<f64> + Sync>(
        &self,
        dev: &Device,
        r: &[R],
        x: &mut [f32],
        iters: u32,
    ) -> Result<(), String> {
        let sys = self.level_system();
        let rhs: Vec<f64> = r.par_iter().map(|&v| v.into()).collect();
        let chi = self.cluster_values(|n| f64::from(x[n]));
        dev.gauss_seidel(&sys, &rhs, x, &chi, iters)
    }

    /// The level's system as the kernel reads it.
    fn level_system(&self) -> LevelSystem<'_> {
        let (lo, hi) = (self.tab.range.lo, self.tab.range.hi);
        let row = |t: &crate::bspline::Table1D| -> Vec<f64> {
            (lo..=hi)
                .flat_map(|i| (-2..=2).map(move |o| t.get(i, o)))
                .collect()
        };
        let (rank_bits, rank_before) = self.cl.of_node.words();
        let (order, class_ends) = self.relaxation_classes();
        LevelSystem {
            degree: self.degree,
            depth: self.d,
            brood_nbrs: &self.level.brood_nbrs,
            brood_key: self.level.brood_keys(),
            lo,
            hi,
            stencil: &self.tab.stencil,
            mass: row(&self.tab.mass),
            stiff: row(&self.tab.stiff),
            rank_bits,
            rank_before,
            omega: &self.cl.omega,
            first: &self.cl.first,
            vals: &self.cl.vals,
            order,
            class_ends,
        }
    }

    /// The nodes with a function, grouped as the CPU sweep visits them: by block colour, then
    /// by node colour (see [`Op::gauss_seidel_cpu`]). Within a class the order is free: its
    /// nodes share no coefficient and no cluster, so they can be relaxed at once.
    fn relaxation_classes(&self) -> (Vec<u32>, Vec<usize>) {
        let blocks = self.colour_blocks();
        let colours = self.node_colours() as usize;
        let mut order = Vec::with_capacity(self.level.len());
        let mut ends = Vec::with_capacity(8 * colours);
        for list in &blocks {
            // Per node colour, this block colour's nodes, gathered in parallel over blocks.
            let per_block: Vec<Vec<Vec<u32>>> = list
                .par_iter()
                .map(|&(b0, b1)| {
                    let mut by_colour = vec![Vec::new(); colours];
                    for n in 8 * b0..8 * b1 {
                        let i = self.index(n);
                        if self.tab.range.contains(i) {
                            by_colour[self.node_colour(n, i) as usize].push(n);
                        }
                    }
                    by_colour
                })
                .collect();
            for c in 0..colours {
                for b in &per_block {
                    order.extend_from_slice(&b[c]);
                }
                ends.push(order.len());
            }
        }
        (order, ends)
    }

    /// The colour of node `n` (function index `i`): see [`Op::gauss_seidel_cpu`], whose
    /// sweep finds the node of each colour per brood with [`Op::child_of_colour`].
    #[inline]
    fn node_colour(&self, n: u32, i: [i64; 3]) -> u32 {
        if self.degree == 1 {
            n & 7
        } else {
            let m = i64::from(self.degree) + 1;
            (i[0].rem_euclid(m) + m * (i[1].rem_euclid(m) + m * i[2].rem_euclid(m))) as u32
        }
    }
}
