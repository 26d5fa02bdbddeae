//! Stage 2b (issue 16, beyond ALGORITHM.md): the local noise of the samples, and the finest
//! splat depth it allows.
//!
//! The reference splats every sample at the depth where the density estimator counts `S`
//! samples per node (§3.5), whatever the noise; on a noisy scan the finest cells are then
//! smaller than the noise and the surface follows it. Here the noise is measured where it is,
//! and each sample's splat depth is lowered so that its cells are wider than the noise
//! around it: clean regions keep the density's depth (full detail), noisy ones are splatted
//! coarser, as a larger `S` would do, but only there.
//!
//! **Measuring.** The samples' moments (weight, weighted sums of `p` and `p pᵀ`) are summed
//! into the cells of every depth. For a sample, the 3×3×3 cells around it are examined from
//! the finest depth upwards; the first depth at which that neighbourhood is *flat* (its
//! covariance's smallest eigenvalue below `FLAT²` times the middle one, with at least
//! `MIN_SAMPLES` samples) gives a plane. Over that plane, a quadratic height field
//! `r ≈ a + bu + cv + du² + euv + fv²` is fitted by least squares to the offsets `r` of all
//! the samples of the neighbourhood, and the noise `σ` is the standard deviation of what it
//! leaves (`n − 6` degrees of freedom). The fit takes out the surface's position, slope and
//! curvature, so a clean curved surface reads almost no noise, and noise reads as itself, a
//! Gaussian's σ. Two earlier estimates measured clean shapes as noisy: the plane's own
//! residual `√λ_min` (curvature and creases: 6–18 % less accurate on the clean rocker arm
//! and fandisk), then the spread of the plane offsets within finer cells, which on clean
//! clouds could be measured only where few samples share a fine cell, that is where the
//! surface bends (3–8 % less accurate on the clean bunny, fandisk and rocker arm at depths 8
//! and 9). Where no depth is flat, nothing is measured.
//!
//! **Resolved or not.** A neighbourhood stops being flat below some depth for one of two
//! reasons: noise thicker than `FLAT` allows, or shape (a bend, a horn) that the sampling
//! hardly resolves. On a sparse scan the quadratic fit then reads the unresolved shape as
//! noise (CGAL's 1,435-point oni lost a horn to it). So a sample's residual counts only when
//! its next finer neighbourhood held at least `RESOLVE_SAMPLES` samples and was *not* flat:
//! there the samples were dense enough to show the surface, and it was thick. Where the
//! finer neighbourhood held too few samples to tell, the sample's noise is 0, unless it is
//! *thick*: at least `THICK_SHARE` of the width of its plane's cells, at depth `THICK_DEPTH`
//! or finer. There the neighbourhood was flat and the fit took its bend out, and a cell of at
//! most 1/64 of the cube holds no whole feature whose leftover could be that thick; so it is
//! noise too thin to bend the finer neighbourhood's few samples (noise of 0.1–0.3 % of the
//! diagonal on a 100,000-point bunny read 0 before: the 0.25 %-noise bunny, 4 % less accurate,
//! and the low half of the noise ramps). Clean clouds read under a fifth of a cell where
//! nothing was resolved (90 % of their samples; the oni's reach 0.3, but at depths 3 to 5).
//! Clean scans, dense or sparse, then keep the reference's splat depths.
//!
//! **Choosing.** A sample whose density gives cells of width `h` and whose noise is `σ` is
//! splatted as if its samples per node were `S · min(1 + (κσ/h)², 6)`, `κ = 3`: the density
//! estimator is queried again at that larger count ([`Density::query_scaled`]), which gives
//! the sample both its lower depth and the area weight of that depth, exactly what an
//! explicit `--samples-per-node` that large would give it. Where the noise is well below the
//! spacing nothing changes; where it is larger the cells grow with it, by at most 1.3 levels (2.5 on smooth shapes, below).
//! (An earlier version lowered only the depth, `d − ½ log2(1 + r²)`, and kept the area weight
//! of the density's own depth. That weight is read from the finest cells, where noise
//! scatters the samples through the volume and the count per cell is low and uneven; the
//! vector field then inherited that unevenness. With the same lowering for every noisy
//! sample, it was 2–6 % less accurate than the equivalent `--samples-per-node` on the bunny's
//! noise ramp, band by band; queried again, the two agree.) `κ = 3` and the cap were chosen at
//! depths 8 to 10 on the bunny with noise of 0.25 % and 0.5 % of its diagonal, the bunny and
//! fandisk noise ramps, and spot and the rocker arm with 0.5 % noise (bench/noise/run.py):
//! without the cap, the strong noise of the rocker arm smooths its thin ring away (7.4 against
//! 5.8 × 10⁻⁴ of the diagonal), and a flatter or weaker mapping leaves the ramps' less noisy
//! parts under-smoothed. A curvature-aware choice (larger cells where the fitted height field
//! is flat, the bias–variance optimum of a local fit) was tried and did not separate the
//! shapes that want more smoothing (spot) from those that want less (the rocker arm): the
//! curvature measured on noisy samples is mostly noise.
//!
//! The cap was 8 (1.5 levels) and the screening's power 1/3 (below) until 2026-12-07, when
//! both were chosen again together on every noisy cloud of bench/noise/run.py, the shared
//! ones and the eight of `--inputs unseen` (so those are no longer clouds the constants were
//! not chosen on). Measured per noise band, the noisiest sixth of the bunny's ramp was
//! farther from the truth than with `--samples-per-node 10` everywhere (the cap then gave it
//! 12, with half its screening): strong noise was smoothed too far, and a larger cap made it
//! worse. The cap of 6 alone helped the ramps by 1–3 % and cost spot with 0.5 % noise 4 %;
//! with the screening's power raised to 1/2 as well, the noisy clouds at depths 8 to 10 are
//! 0.94–1.01 × their distance before: the bunny's ramp 0.95–0.96 ×, spot's 0.95 ×, the
//! 0.5 %-noise bunny 0.94 ×, the rocker arm's and the fandisk's ramps 1.00–1.01 ×. Caps of
//! 4 and 5, `κ` of 2–5 and other shapes of the mapping (`1 + (κσ/h)^p`, `p` = 1 or 1.5) were
//! no better on the whole. The cap of 6 lost on the million-point bunny's ramp (2 % at
//! depths 9 and 10), whose finer density depth needs a larger factor for the same cells
//! (docs/noise.md, *A denser ramp*); it now grows with the density (*Denser clouds*, below).
//!
//! What does separate them is whether the shape is still a quadratic at a coarser scale
//! ([`MeasuredNoise::coarser`]): the quadratic height field fitted over the plane of the measuring
//! cell's parent (a neighbourhood twice as wide) leaves no more than the noise on a smooth
//! shape, and more near ears, horns, thin parts and creases, which a quadratic that wide does
//! not hold. Where it leaves at most `STILL_QUADRATIC = 1.1` times the measuring depth's
//! residual (smoothed over the noisy samples around, as the noise is), the cap is
//! `SMOOTH_MAX_FACTOR = 32` instead of 6 (cells up to 2.3 times as wide again). Measured on
//! clouds none of the constants had been chosen on then (docs/noise.md, *Eight more clouds*):
//! the sphere's noise ramp 13–29 % nearer the truth (the cap had held it at 1.20–1.24 × the
//! best single `--samples-per-node`, S = 20), the torus with 0.5 % noise 5–33 % nearer, the
//! million-point spot with 0.5 % noise 1–5 % nearer, and every other noisy cloud, shared or
//! not, within 0.5 % of before; clean clouds do not reach the cap and are the same bytes. With
//! 1.25 in place of 1.1, the bunny's ramp along z lost 1 %. (Measured first outside spsr, with
//! bench/noise/scale_residual.py: at twice the measuring scale the residual of the sphere's
//! noisiest samples grows by 9 %, that of spot, the rocker arm and the bunny by 27–80 %.)
//!
//! **Denser clouds.** The cap of 6 was chosen on clouds of 100,000 points, whose density
//! depths lie near 7.5. A denser cloud's density depth is finer, so the same noise needs a
//! larger factor to reach cells as wide, and its extra samples average the noise further
//! within each cell. Balancing the two errors of a cell of width `w` (the noise left after
//! averaging its samples, variance `σ²/(ρw²)` at areal density `ρ`, against the shape's bend
//! across it, `∝ w⁴`) puts the best width at `w ∝ σ^(1/3) ρ^(-1/6)`: it deepens by a third of a
//! level for each level the density deepens, so the lowering below the density's depth should
//! grow by two thirds of a level. Where the shape is not known to be smooth, the cap grows by
//! half that ([`dense_cap`]): the splat may be lowered a further `DENSE_LEVELS = ½` level for
//! each level of density depth past `DENSE_FROM = 7.5` (the cap doubles per level). The
//! screening keeps the cap of 6's share, `6^(-1/2)`: where the tree's depth already holds the
//! splat (a million points at depth 8), a larger factor would only lower the screening, and
//! that cost the million-point bunny's ramp 4 % there (2.78 against 2.67 × 10⁻⁴ of the
//! diagonal, with a third of a level). Measured on six noisy clouds of a million points (the
//! bunny's ramp and spot's 0.5 % noise, and four sampled from the ground-truth meshes: noise
//! ramps on the rocker arm, the fandisk and the torus, 0.5 % noise on the bunny) at depths 8
//! to 10, against the fixed cap: 0.754–1.008 × the distance to the truth, 0.947 × on average
//! (the rocker arm's ramp 0.75 × at depth 9, the torus's 0.84 ×, spot 0.91 ×, the bunny
//! 0.94 ×; docs/noise.md, *Denser clouds*). A third of a level was 0.747–1.003 × and gained
//! less (0.968 × on average); two thirds cost the fandisk's ramp up to 10 %. The
//! 100,000-point noisy clouds, whose density depths are near 7.5, moved by at most 0.4 %.
//!
//! **Screening.** The screening term pulls χ towards ½ at every sample, with the sample's
//! weight; a noisy sample pulls towards a position that is off by its noise. So a sample whose
//! samples per node were multiplied by `factor` keeps `factor^(-1/2)` of its weight in the
//! screening term and in the iso-value ([`DepthAndArea::screen`]; its weight in the vector
//! field is unchanged). Measured at depth 9 with the power 1/3 and the cap of 8 (Chamfer ×
//! 10⁻⁴ of the diagonal, without → with): the bunny's ramp 4.37 → 4.30, the fandisk's 4.19 →
//! 4.09, the 0.25 %-noise bunny 4.55 → 4.33, the rocker arm 5.79 → 5.55, spot 5.65 → 5.08,
//! the 0.5 %-noise bunny 7.48 → 7.51. With that cap, powers of 1/2 and 1 helped spot and the
//! 0.25 %-noise bunny a little more but cost the 0.5 %-noise bunny 2–11 %; with the cap of 6
//! (above), 1/2 helps all three, and 2/3 and 1 cost the rocker arm's ramp 2–6 %. (Lowering
//! the screening of noisy samples had been tried before the samples per node were queried
//! again, and was worse on the ramps then.)
//!
//! **Screening depth.** A sample is screened by the cluster of every node that holds it, down
//! to its deepest node; a cluster's point is the mean of its samples. Below a noisy sample's
//! splat the clusters hold few samples (about `S · 4^(d_s − d)` at depth `d`, with `S` samples
//! per node at the density's depth `d_s`), so their means keep most of the noise and pull χ
//! towards it cell by cell: the bumps the coarse splat was chosen to avoid. So a noisy
//! sample is screened only down to the finest depth whose clusters average its noise to at
//! most `SCREEN_AVERAGING = 1` cell width ([`screen_depth`]: `σ / √(S · 4^(d_s − d)) ≤ 2^-d`),
//! half a cell (`SMOOTH_SCREEN_AVERAGING`) where the shape is smooth enough for the cap of 32,
//! since coarser screening loses nothing there; and around it the tree is refined
//! [`REFINE_BELOW_NOISY_SPLAT`] = 1 depth below its splat: χ is smooth there, and the finer
//! functions and cells carry that smooth surface more closely than cells of the splat's width
//! (a clean bunny meshed at depth 7 is 1.2–1.9 × 10⁻⁴ of the diagonal from the truth, at depth
//! 8 0.5–0.7). Either alone lost (bench/noise/run.py's clouds at depth 9): the screening cut
//! at the splat with the tree as it was, 1–2 % on the ramps; the finer tree with the finer
//! clusters screening, 1–6 %, since they then pull χ to the noise. Together, on the shared
//! and own noisy clouds of bench/noise/run.py at depths 8 to 10 (2026-12-08): 0.91–0.99 × their
//! distance before (the bunny's ramp 0.97 ×, the 0.5 %-noise bunny 0.95 ×, spot with 0.5 %
//! noise 0.91 ×); clean clouds and real scans have no noisy samples and are the same bytes
//! (docs/noise.md, *Screening depth*, has the other clouds). The
//! constants (measured on the same clouds at depths 8 to 10): refining two depths gained about
//! 1 % more at 2–3 times the time. One averaging for all shapes: 1 cost the sphere's ramp 2–5 %
//! at depths 8 and 9 and a sphere of 100,000 points with noise of 0.02 of its radius 18 % at
//! depth 9 (its splats lie up to 2.5 levels coarser, and the clusters between their depth and
//! the one 1 allows still follow the noise); 0.7 cost the million-point bunny with 0.5 % noise
//! 3 % at depth 8 (over 0.8 × PoissonRecon) and the 0.5 %-noise bunny 2–4 %; ½ lost up to 4 %
//! on the 0.5 %-noise bunny. Cutting every noisy sample's screening at its splat depth instead
//! cost the million-point clouds 4 % at depth 8, where their clusters at the tree's depth
//! already hold many samples.
//!
//! **Smoothing the estimate.** The noise is smoothed first, twice:
//! each sample takes the median noise of the measured samples in the 3×3×3 cells around it
//! one level above the typical measuring depth, then the median of those medians two levels
//! coarser, so that the splat depth varies slowly across the surface.

use rayon::prelude::*;

use rustc_hash::FxHashMap;

use crate::density::{cell_of, Density, DepthAndArea, Sample, ALL_DEPTHS};
use crate::morton;
use crate::normals::estimate::{eigen_sym3, Sym3};

/// A neighbourhood is flat when `√(λ_min / λ_mid)` is at most this.
const FLAT: f64 = 0.5;

/// Fewest samples in a neighbourhood for its plane fit to count.
const MIN_SAMPLES: f64 = 20.0;

/// Fewest samples in a neighbourhood for its bend to count as noise (see `measure`).
const RESOLVE_SAMPLES: f64 = 15.0;

/// The least noise, as a share of its plane's cell width, that counts where the finer
/// neighbourhood held too few samples to tell (see the module docs, *Resolved or not*).
const THICK_SHARE: f64 = 0.25;

/// The coarsest depth of a plane whose thick noise counts unresolved: cells of 1/64 of the
/// cube or less.
const THICK_DEPTH: u32 = 6;

/// A sample's samples per node are multiplied by `1 + (CELLS_PER_NOISE σ / h)²` (see the
/// module docs).
const CELLS_PER_NOISE: f64 = 3.0;

/// The largest multiplication of a sample's samples per node: its splat depth is lowered by
/// at most 1.3 levels, more in denser clouds ([`dense_cap`]; see the module docs).
const MAX_FACTOR: f64 = 6.0;

/// The density depth past which [`MAX_FACTOR`] grows with the density ([`dense_cap`]): about
/// that of the 100,000-point clouds the cap was chosen on.
const DENSE_FROM: f64 = 7.5;

/// How much further, in levels, a sample's splat may be lowered for each level its density
/// depth lies past [`DENSE_FROM`] ([`dense_cap`]).
const DENSE_LEVELS: f64 = 0.5;

/// The largest multiplication where the shape is still a quadratic one depth coarser than
/// the noise was measured at (see [`STILL_QUADRATIC`]): the splat depth may then be lowered
/// by up to 2.5 levels.
const SMOOTH_MAX_FACTOR: f64 = 32.0;

/// A sample's shape counts as still a quadratic one depth coarser than its noise was
/// measured at when the quadratic height field fitted there leaves at most this multiple of
/// the measuring depth's residual (see the module docs, *Choosing*).
const STILL_QUADRATIC: f64 = 1.1;

/// What the noise stage found, for the user.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct NoiseSummary {
    /// Median noise over the samples where it was measured, counting as 0 those whose
    /// surface the samples do not resolve (see the module docs), in the input's units (in
    /// unit-cube units until [`NoiseSummary::in_units`]).
    pub median: f64,
    /// The same in cells of the finest depth.
    pub median_cells: f64,
    /// Share of the samples where it was measured.
    pub measured: f64,
    /// Share of the samples whose splat depth was lowered.
    pub adapted: f64,
    /// Mean lowering of the splat depth over the adapted samples, in levels.
    pub mean_lowering: f64,
}

impl NoiseSummary {
    /// The summary with its median in the units of a cube `width` wide.
    pub fn in_units(self, width: f64) -> Self {
        NoiseSummary {
            median: self.median * width,
            ..self
        }
    }
}

/// One cell's moments.
#[derive(Debug, Clone, Copy, Default)]
struct Moments {
    w: f64,
    s: [f64; 3],
    ss: Sym3,
}

impl Moments {
    fn of(s: &Sample) -> Self {
        let p = s.pos;
        let w = s.weight;
        Moments {
            w,
            s: p.map(|c| w * c),
            ss: [
                w * p[0] * p[0],
                w * p[1] * p[1],
                w * p[2] * p[2],
                w * p[0] * p[1],
                w * p[0] * p[2],
                w * p[1] * p[2],
            ],
        }
    }

    fn add(&mut self, o: &Moments) {
        self.w += o.w;
        for a in 0..3 {
            self.s[a] += o.s[a];
        }
        for k in 0..6 {
            self.ss[k] += o.ss[k];
        }
    }

    /// What the moments of `count` samples look like; `None` with too few samples.
    fn patch(&self, count: f64) -> Option<Patch> {
        if count < RESOLVE_SAMPLES || self.w <= 0.0 {
            return None;
        }
        let m = self.s.map(|c| c / self.w);
        let idx = [(0, 0), (1, 1), (2, 2), (0, 1), (0, 2), (1, 2)];
        let cov: Sym3 = std::array::from_fn(|k| {
            let (i, j) = idx[k];
            self.ss[k] / self.w - m[i] * m[j]
        });
        let (l, v) = eigen_sym3(&cov);
        let lo = l[0].max(0.0);
        let flat = l[1] > 0.0 && lo <= FLAT * FLAT * l[1];
        if flat && count < MIN_SAMPLES {
            return None;
        }
        Some(if flat {
            Patch::Flat(Plane {
                centre: m,
                normal: v[0],
                tangents: [v[1], v[2]],
            })
        } else {
            Patch::Bent
        })
    }
}

/// A neighbourhood with enough samples to tell its shape.
#[derive(Debug, Clone, Copy)]
enum Patch {
    /// Flat, with the plane fitted to it.
    Flat(Plane),
    /// Not flat: noise or shape thicker than `FLAT` allows.
    Bent,
}

impl Patch {
    fn plane(&self) -> Option<&Plane> {
        match self {
            Patch::Flat(p) => Some(p),
            Patch::Bent => None,
        }
    }
}

/// A plane fitted to a flat neighbourhood.
#[derive(Debug, Clone, Copy)]
struct Plane {
    centre: [f64; 3],
    normal: [f64; 3],
    tangents: [[f64; 3]; 2],
}

impl Plane {
    fn offset(&self, p: [f64; 3]) -> f64 {
        dot_from(p, self.centre, self.normal)
    }

    /// `p`'s coordinates along the plane's tangents, from its centre.
    fn along(&self, p: [f64; 3]) -> [f64; 2] {
        self.tangents.map(|t| dot_from(p, self.centre, t))
    }
}

/// `(p − o) · v`.
fn dot_from(p: [f64; 3], o: [f64; 3], v: [f64; 3]) -> f64 {
    (0..3).map(|a| (p[a] - o[a]) * v[a]).sum()
}

/// The Morton code of cell `c`.
fn code_of_cell(c: [i64; 3]) -> u64 {
    morton::encode(c.map(|v| v as u64))
}

/// Bits of a cell's Morton code that pick its shard of a [`CodeIndex`]: 4,096 shards, the
/// cells of depth 4, enough to share a depth's cells evenly among the threads.
const SHARD_BITS: u32 = 12;

/// The position of each of a depth's occupied cells by its Morton code. The codes are sorted,
/// so each shard holds a run of consecutive cells and the shards are built in parallel: one
/// map filled cell by cell was most of the noise stage's serial time.
struct CodeIndex {
    shift: u32,
    shards: Vec<FxHashMap<u64, u32>>,
}

impl CodeIndex {
    /// The index of the sorted `codes` of cells at `depth`.
    fn new(codes: &[u64], depth: u32) -> Self {
        let bits = (3 * depth).min(SHARD_BITS);
        let shift = 3 * depth - bits;
        let bounds: Vec<usize> = (0..=1u64 << bits)
            .map(|s| codes.partition_point(|&c| c >> shift < s))
            .collect();
        let shards = bounds
            .par_windows(2)
            .map(|w| {
                let mut m = FxHashMap::with_capacity_and_hasher(w[1] - w[0], Default::default());
                m.extend((w[0]..w[1]).map(|k| (codes[k], k as u32)));
                m
            })
            .collect();
        CodeIndex { shift, shards }
    }

    /// The position of the cell with Morton code `code`, if occupied; codes of cells outside
    /// the cube fall past the last shard.
    #[inline]
    fn get(&self, code: u64) -> Option<usize> {
        let shard = self.shards.get((code >> self.shift) as usize)?;
        shard.get(&code).map(|&k| k as usize)
    }
}

/// The samples sorted by their finest cell's Morton code, `(code, sample)`.
#[derive(Clone, Copy)]
struct Sorted<'a> {
    samples: &'a [Sample],
    sorted: &'a [(u64, u32)],
}

impl Sorted<'_> {
    /// The moments and count of the sorted samples `a..b`, added in that order.
    fn moments(&self, (a, b): (u32, u32)) -> (Moments, f64) {
        let mut m = Moments::default();
        for &(_, i) in &self.sorted[a as usize..b as usize] {
            m.add(&Moments::of(&self.samples[i as usize]));
        }
        (m, f64::from(b - a))
    }
}

/// The occupied cells of one depth, in Morton order: each cell's code, its moments and sample
/// count (until the patches are made), and its samples as a range of the samples sorted by
/// their finest cell's code (a cell's samples are contiguous there at every depth).
///
/// The finest depth stores no moments: its cells, most of the cells of all depths, hold a
/// sample or two each, and their moments are summed from the samples when read
/// ([`Depth::moments_at`]), the same sums in the same order (issue 20: they were the noise
/// stage's largest array, 88 bytes a cell).
struct Depth {
    codes: Vec<u64>,
    moments: Vec<(Moments, f64)>,
    /// Whether the moments are summed from the samples when read (the finest depth).
    summed: bool,
    ranges: Vec<(u32, u32)>,
    index: CodeIndex,
    /// Each cell's children as a range of the next finer depth's cells (empty at the finest).
    children: Vec<(u32, u32)>,
}

impl Depth {
    /// The cells of the finest depth from the sorted samples: a cell's moments are its
    /// samples' added in the samples' order, summed when read.
    fn finest(src: Sorted, top: u32) -> Self {
        let runs = runs(src.sorted.len(), |k| src.sorted[k].0);
        let codes = runs
            .iter()
            .map(|&(a, _)| src.sorted[a as usize].0)
            .collect();
        let mut depth = Depth::new(codes, Vec::new(), runs, top);
        depth.summed = true;
        depth
    }

    /// The moments and sample count of cell `k`.
    #[inline]
    fn moments_at(&self, k: usize, src: Sorted) -> (Moments, f64) {
        if self.summed {
            src.moments(self.ranges[k])
        } else {
            self.moments[k]
        }
    }

    /// The cells of the next coarser depth: a cell's moments are its children's added in
    /// Morton order. `depth` is the new cells' depth.
    fn parent(&self, depth: u32, src: Sorted) -> Self {
        let runs = runs(self.codes.len(), |k| self.codes[k] >> 3);
        let moments = runs
            .par_iter()
            .map(|&(a, b)| {
                let mut m = Moments::default();
                let mut n = 0.0;
                for k in a as usize..b as usize {
                    let (cm, cn) = self.moments_at(k, src);
                    m.add(&cm);
                    n += cn;
                }
                (m, n)
            })
            .collect();
        let codes = runs
            .iter()
            .map(|&(a, _)| self.codes[a as usize] >> 3)
            .collect();
        let ranges = runs
            .iter()
            .map(|&(a, b)| (self.ranges[a as usize].0, self.ranges[b as usize - 1].1))
            .collect();
        let mut up = Depth::new(codes, moments, ranges, depth);
        up.children = runs;
        up
    }

    fn new(
        codes: Vec<u64>,
        moments: Vec<(Moments, f64)>,
        ranges: Vec<(u32, u32)>,
        depth: u32,
    ) -> Self {
        let index = CodeIndex::new(&codes, depth);
        Depth {
            codes,
            moments,
            summed: false,
            ranges,
            index,
            children: Vec::new(),
        }
    }

    /// The position of the cell at `c`, if occupied.
    #[inline]
    fn find(&self, c: [i64; 3]) -> Option<usize> {
        self.index.get(code_of_cell(c))
    }

    /// The cell coordinates of the cell at position `k`.
    fn cell(&self, k: usize) -> [i64; 3] {
        morton::decode(self.codes[k]).map(|v| v as i64)
    }
}

/// What the measure keeps of one depth's patches. A plane is never fitted at the finest
/// depth, whose patches are read only as the next finer neighbourhood of a coarser plane's
/// cell, for whether they are bent; so there only that bit is kept (the finest depth holds
/// most of the cells, and a patch with its plane is a hundred bytes).
enum Kept {
    Patches(Vec<Option<Patch>>),
    Bent(Vec<bool>),
}

impl Kept {
    /// The plane of cell `k`'s neighbourhood, if it is flat (never at the finest depth).
    fn plane(&self, k: usize) -> Option<&Plane> {
        match self {
            Kept::Patches(p) => p[k].as_ref().and_then(Patch::plane),
            Kept::Bent(_) => None,
        }
    }

    /// Whether cell `k`'s neighbourhood held enough samples and was not flat.
    fn bent(&self, k: usize) -> bool {
        match self {
            Kept::Patches(p) => matches!(p[k], Some(Patch::Bent)),
            Kept::Bent(b) => b[k],
        }
    }
}

/// The patches of depth `d` (see [`patches`]), kept as [`Kept`] says for a depth that is the
/// finest or not.
fn kept_patches(depths: &mut [Depth], d: usize, src: Sorted) -> Kept {
    if d + 1 == depths.len() {
        Kept::Bent(patches(depths, d, src, |p| matches!(p, Some(Patch::Bent))))
    } else {
        Kept::Patches(patches(depths, d, src, |p| p))
    }
}

/// `keep` of the patch of each cell's 3×3×3 neighbourhood at depth `d`, where it holds enough
/// samples; the depth's moments are released once read.
///
/// The neighbours are found parent by parent: the children of the parent's 3×3×3 neighbours
/// (one lookup each) fill a 6×6×6 grid, which holds the neighbourhood of every child of the
/// parent. That is a quarter of the lookups of finding each cell's 27 neighbours on its own,
/// and the sums are the same, in the same order. Where the moments are summed from the
/// samples (the finest depth), those of the cells around the parent's children are summed
/// once for them all ([`AroundChildren`]). Only depth `d`'s moments are read (and released),
/// so the depths may be taken in any order.
fn patches<T: Send>(
    depths: &mut [Depth],
    d: usize,
    src: Sorted,
    keep: impl Fn(Option<Patch>) -> T + Sync,
) -> Vec<T> {
    let out = if d == 0 {
        (0..depths[0].codes.len())
            .map(|k| {
                let (m, n) = depths[0].moments_at(k, src);
                keep(m.patch(n))
            })
            .collect()
    } else {
        let (up, here, keep) = (&depths[d - 1], &depths[d], &keep);
        (0..up.codes.len())
            .into_par_iter()
            .flat_map_iter(|p| {
                let grid = Neighbourhood::of(up, here, p);
                // Only where the moments are summed when read is it worth keeping them.
                let mut around = here.summed.then(|| AroundChildren::new(&grid));
                let (a, b) = up.children[p];
                (a as usize..b as usize).map(move |k| {
                    let mut m = Moments::default();
                    let mut n = 0.0;
                    grid.for_each_around(here.cell(k), |q, j| {
                        let (qm, qn) = match &mut around {
                            Some(around) => around.moments(q, j, here, src),
                            None => here.moments[j],
                        };
                        m.add(&qm);
                        n += qn;
                    });
                    keep(m.patch(n))
                })
            })
            .collect()
    };
    depths[d].moments = Vec::new();
    out
}

/// The moments of the 4×4×4 cells around the children of one parent cell, each read once
/// (summed from the samples where the depth stores none) and then kept for the other
/// children: a finest cell's samples are summed for the 8 parents around it instead of the 27
/// cells around it.
struct AroundChildren {
    /// The lowest corner of the 4×4×4 cells.
    origin: [i64; 3],
    moments: [(Moments, f64); 64],
    /// Which of `moments` are read.
    read: u64,
}

impl AroundChildren {
    fn new(grid: &Neighbourhood) -> Self {
        AroundChildren {
            // The grid starts one cell below the block around the parent's children.
            origin: grid.origin.map(|v| v + 1),
            moments: [(Moments::default(), 0.0); 64],
            read: 0,
        }
    }

    /// The moments of cell `j` of `here`, at `q` (around one of the parent's children).
    #[inline]
    fn moments(&mut self, q: [i64; 3], j: usize, here: &Depth, src: Sorted) -> (Moments, f64) {
        let r: [i64; 3] = std::array::from_fn(|a| q[a] - self.origin[a]);
        let slot = (r[0] + 4 * (r[1] + 4 * r[2])) as usize;
        if self.read & (1 << slot) == 0 {
            self.moments[slot] = here.moments_at(j, src);
            self.read |= 1 << slot;
        }
        self.moments[slot]
    }
}

/// The cells of one depth around the children of one parent cell: a 6×6×6 grid over the
/// children of the parent's 3×3×3 neighbours, each slot a cell's position or `NO_CELL`.
struct Neighbourhood {
    origin: [i64; 3],
    slots: [u32; 216],
}

const NO_CELL: u32 = u32::MAX;

impl Neighbourhood {
    /// The grid around the children of cell `p` of `up`, the cells of `here` (one depth finer).
    fn of(up: &Depth, here: &Depth, p: usize) -> Self {
        let pc = up.cell(p);
        let mut grid = Neighbourhood {
            origin: pc.map(|v| 2 * (v - 1)),
            slots: [NO_CELL; 216],
        };
        for_each_neighbour(pc, |q| {
            let Some(j) = up.find(q) else { return };
            let (a, b) = up.children[j];
            for k in a..b {
                let slot = grid
                    .slot(here.cell(k as usize))
                    .expect("a child of a neighbour");
                grid.slots[slot] = k;
            }
        });
        grid
    }

    #[inline]
    fn slot(&self, c: [i64; 3]) -> Option<usize> {
        let r: [i64; 3] = std::array::from_fn(|a| c[a] - self.origin[a]);
        r.iter()
            .all(|v| (0..6).contains(v))
            .then(|| (r[0] + 6 * (r[1] + 6 * r[2])) as usize)
    }

    /// Calls `f` with the cell coordinates and the position of each occupied cell of the
    /// 3×3×3 cells around `c` (a child of the grid's parent), in [`for_each_neighbour`]'s
    /// order.
    #[inline]
    fn for_each_around(&self, c: [i64; 3], mut f: impl FnMut([i64; 3], usize)) {
        for_each_neighbour(c, |q| {
            let k = self.slots[self.slot(q).expect("within the grid")];
            if k != NO_CELL {
                f(q, k as usize);
            }
        });
    }
}

/// The runs of equal keys among `len` sorted keys `key(k)`, as `(first, end)`.
fn runs(len: usize, key: impl Fn(usize) -> u64) -> Vec<(u32, u32)> {
    let mut out = Vec::new();
    let mut start = 0;
    for k in 1..=len {
        if k == len || key(k) != key(start) {
            out.push((start as u32, k as u32));
            start = k;
        }
    }
    out
}

/// The cells of every depth `0..=top` (indexed by depth) and the samples sorted by their
/// finest cell's Morton code, `(code, sample)`.
fn depths(samples: &[Sample], top: u32) -> (Vec<Depth>, Vec<(u64, u32)>) {
    let mut sorted: Vec<(u64, u32)> = samples
        .par_iter()
        .enumerate()
        .map(|(i, s)| {
            (
                morton::encode(cell_of(s.pos, top).map(|v| v as u64)),
                i as u32,
            )
        })
        .collect();
    sorted.par_sort_unstable();
    let src = Sorted {
        samples,
        sorted: &sorted,
    };
    let mut out = vec![Depth::finest(src, top)];
    for d in (0..top).rev() {
        let up = out.last().expect("the finest depth").parent(d, src);
        out.push(up);
    }
    out.reverse();
    (out, sorted)
}

/// Each sample's noise `σ` and the depth its plane was fitted at, `None` where no depth is
/// flat or the quadratic fit is not determined.
///
/// Each sample belongs to the cell of its finest flat depth; the noise of that cell is the
/// residual of the quadratic height field fitted, over the cell's plane, to the offsets of
/// the samples in the cell's 3×3×3 neighbourhood, and counts only where the next finer
/// neighbourhood resolved the surface or the noise is thick (else 0; the module docs say
/// why).
///
/// The cells are kept in Morton order, so that a cell's parent, its samples and (mostly) its
/// neighbours lie close in memory, and every sum is taken in an order fixed by the samples'
/// order and positions alone.
pub fn measure(samples: &[Sample], top: u32) -> Measured {
    let (mut depths, sorted) = depths(samples, top);
    let src = Sorted {
        samples,
        sorted: &sorted,
    };
    // The finest depth first: the moments of the depth above it, the largest stored, are
    // released before any plane is kept.
    let mut flat: Vec<Kept> = (0..depths.len())
        .rev()
        .map(|d| kept_patches(&mut depths, d, src))
        .collect();
    flat.reverse();
    let mut code_of = vec![0u64; samples.len()];
    for &(c, i) in &sorted {
        code_of[i as usize] = c;
    }
    // The position of sample `i`'s cell at depth `d`.
    let cell_at = |i: usize, d: u32| -> usize {
        let code = code_of[i] >> (3 * (top - d));
        depths[d as usize]
            .index
            .get(code)
            .expect("an occupied cell")
    };
    // Each sample's finest flat depth and cell there.
    let home: Vec<Option<(u32, u32)>> = (0..samples.len())
        .into_par_iter()
        .map(|i| {
            (1..top).rev().find_map(|d| {
                let k = cell_at(i, d);
                flat[d as usize].plane(k).map(|_| (d, k as u32))
            })
        })
        .collect();
    // Whether noise is what kept each sample's next finer neighbourhood from being flat:
    // it held enough samples, and was bent. Where it held too few, the surface is not
    // resolved finer than the plane's depth, and the plane's residual may be shape.
    let resolved: Vec<bool> = home
        .par_iter()
        .enumerate()
        .map(|(i, h)| h.is_some_and(|(d, _)| flat[d as usize + 1].bent(cell_at(i, d + 1))))
        .collect();
    // The noise of every cell some sample's plane was fitted at.
    let mut wanted: Vec<(u32, u32)> = home.iter().flatten().copied().collect();
    wanted.par_sort_unstable();
    wanted.dedup();
    let fit_at = |d: u32, k: usize| -> Option<f64> {
        let depth = &depths[d as usize];
        let plane = flat[d as usize].plane(k)?;
        let w = 1.0 / (1u64 << d) as f64;
        let mut fit = QuadricFit::default();
        for_each_neighbour(depth.cell(k), |q| {
            let Some(j) = depth.find(q) else { return };
            let (a, b) = depth.ranges[j];
            for &(_, i) in &sorted[a as usize..b as usize] {
                let p = samples[i as usize].pos;
                let [u, v] = plane.along(p).map(|x| x / w);
                fit.add(u, v, plane.offset(p) / w);
            }
        });
        fit.residual().map(|r| r * w)
    };
    let fitted: Vec<Option<f64>> = wanted
        .par_iter()
        .map(|&(d, k)| fit_at(d, k as usize))
        .collect();
    // Each sample's noise, and the position of its plane's cell among `wanted`.
    let noise: Vec<Option<(f64, u32, usize)>> = home
        .par_iter()
        .zip(&resolved)
        .map(|(h, &resolved)| {
            let (d, k) = (*h)?;
            let at = wanted.binary_search(&(d, k)).expect("a wanted cell");
            let sigma = fitted[at]?;
            let thick = d >= THICK_DEPTH && sigma >= THICK_SHARE / (1u64 << d) as f64;
            Some((if resolved || thick { sigma } else { 0.0 }, d, at))
        })
        .collect();
    // The cell one depth coarser than a wanted cell.
    let parent = |(d, k): (u32, u32)| -> Option<(u32, u32)> {
        let code = depths[d as usize].codes[k as usize] >> 3;
        let up = depths.get(d.checked_sub(1)? as usize)?;
        Some((
            d - 1,
            up.index.get(code).expect("an occupied parent") as u32,
        ))
    };
    // The residual one depth coarser, fitted once per parent of a noisy sample's cell.
    let mut parents: Vec<(u32, u32)> = noise
        .iter()
        .flatten()
        .filter(|n| n.0 > 0.0)
        .filter_map(|&(_, _, at)| parent(wanted[at]))
        .collect();
    parents.par_sort_unstable();
    parents.dedup();
    let parent_fitted: Vec<Option<f64>> = parents
        .par_iter()
        .map(|&(d, k)| fit_at(d, k as usize))
        .collect();
    noise
        .par_iter()
        .map(|n| {
            let (sigma, depth, at) = (*n)?;
            let coarser = (sigma > 0.0)
                .then(|| parent(wanted[at]))
                .flatten()
                .and_then(|p| parent_fitted[parents.binary_search(&p).expect("a parent")])
                .zip(fitted[at])
                .map_or(f64::INFINITY, |(c, own)| c / own);
            Some(MeasuredNoise {
                sigma,
                depth,
                coarser,
            })
        })
        .collect()
}

/// Calls `f` with each of the 3×3×3 cells around `c` (itself included) inside the cube's
/// positive octant.
fn for_each_neighbour(c: [i64; 3], mut f: impl FnMut([i64; 3])) {
    for dz in -1..=1 {
        for dy in -1..=1 {
            for dx in -1..=1 {
                let q = [c[0] + dx, c[1] + dy, c[2] + dz];
                if q.iter().all(|&v| v >= 0) {
                    f(q);
                }
            }
        }
    }
}

/// The sums a least-squares fit of the samples' offsets `r` from a plane by a quadratic
/// height field over the plane, `r ≈ βᵀx` with `x = [1, u, v, u², uv, v²]`, needs.
/// (Also the curvature estimate of `--depth auto`, `super::resolution`.)
#[derive(Debug, Clone, Copy, Default)]
pub(crate) struct QuadricFit {
    /// `Σ xxᵀ`.
    xx: [[f64; 6]; 6],
    /// `Σ x r`.
    xr: [f64; 6],
    /// `Σ r²`.
    rr: f64,
    n: f64,
}

impl QuadricFit {
    /// Adds a sample at `(u, v)` over the plane, `r` off it.
    pub(crate) fn add(&mut self, u: f64, v: f64, r: f64) {
        let x = [1.0, u, v, u * u, u * v, v * v];
        for i in 0..6 {
            for j in i..6 {
                self.xx[i][j] += x[i] * x[j];
            }
            self.xr[i] += x[i] * r;
        }
        self.rr += r * r;
        self.n += 1.0;
    }

    /// The standard deviation of the offsets about the fitted height field: what remains
    /// once the surface's position, slope and curvature are taken out. `None` with too few
    /// samples or samples that do not span the plane.
    pub(crate) fn residual(&self) -> Option<f64> {
        let beta = self.coefficients()?;
        let rss = self.rr - (0..6).map(|i| beta[i] * self.xr[i]).sum::<f64>();
        Some((rss.max(0.0) / (self.n - 6.0)).sqrt())
    }

    /// The fitted height field's coefficients `β` (`r ≈ βᵀ[1, u, v, u², uv, v²]`); `None`
    /// as for [`QuadricFit::residual`].
    pub(crate) fn coefficients(&self) -> Option<[f64; 6]> {
        if self.n < MIN_SAMPLES {
            return None;
        }
        let mut a = self.xx;
        for i in 0..6 {
            for j in 0..i {
                a[i][j] = a[j][i];
            }
        }
        cholesky_solve(a, self.xr)
    }
}

/// Solves `a x = b` for a symmetric positive definite `a`; `None` when a pivot is not
/// clearly positive (the system is close to singular).
fn cholesky_solve<const N: usize>(mut a: [[f64; N]; N], mut b: [f64; N]) -> Option<[f64; N]> {
    let trace: f64 = (0..N).map(|i| a[i][i]).sum();
    for j in 0..N {
        let mut d = a[j][j];
        for k in 0..j {
            d -= a[j][k] * a[j][k];
        }
        if d.is_nan() || d <= 1e-12 * trace {
            return None;
        }
        let d = d.sqrt();
        a[j][j] = d;
        for i in j + 1..N {
            let mut s = a[i][j];
            for k in 0..j {
                s -= a[i][k] * a[j][k];
            }
            a[i][j] = s / d;
        }
    }
    for i in 0..N {
        for k in 0..i {
            b[i] -= a[i][k] * b[k];
        }
        b[i] /= a[i][i];
    }
    for i in (0..N).rev() {
        for k in i + 1..N {
            b[i] -= a[k][i] * b[k];
        }
        b[i] /= a[i][i];
    }
    Some(b)
}

/// The second smoothing pass is this many depths coarser than the first.
const SECOND_SMOOTHING: u32 = 2;

/// Smooths the noise and what goes with it: for each of the `N` per-sample values, each
/// sample takes the median of the measured samples' values (those not NaN) in the 3×3×3
/// cells around it at depth `d`; that value's `empty` where none was measured.
///
/// The samples are grouped by cell through one parallel sort of their cells' Morton codes
/// (not a map filled sample by sample, which was serial), once for all the values; a median
/// does not depend on the order of its values, so neither does the result.
fn smooth<const N: usize>(
    samples: &[Sample],
    values: [&[f64]; N],
    d: u32,
    empty: [f64; N],
) -> [Vec<f64>; N] {
    let mut sorted: Vec<(u64, u32)> = samples
        .par_iter()
        .enumerate()
        .map(|(i, s)| (code_of_cell(cell_of(s.pos, d)), i as u32))
        .collect();
    sorted.par_sort_unstable();
    let cells = runs(sorted.len(), |k| sorted[k].0);
    let codes: Vec<u64> = cells
        .par_iter()
        .map(|&(a, _)| sorted[a as usize].0)
        .collect();
    let index = CodeIndex::new(&codes, d);
    let medians: Vec<[f64; N]> = codes
        .par_iter()
        .map_init(Vec::new, |buf: &mut Vec<f64>, &code| {
            let c = morton::decode(code).map(|v| v as i64);
            std::array::from_fn(|v| {
                buf.clear();
                for_each_neighbour(c, |q| {
                    let Some(k) = index.get(code_of_cell(q)) else {
                        return;
                    };
                    let (a, b) = cells[k];
                    let around = sorted[a as usize..b as usize]
                        .iter()
                        .map(|&(_, i)| values[v][i as usize]);
                    buf.extend(around.filter(|x| !x.is_nan()));
                });
                if buf.is_empty() {
                    return empty[v];
                }
                let m = buf.len() / 2;
                *buf.select_nth_unstable_by(m, f64::total_cmp).1
            })
        })
        .collect();
    let at: Vec<usize> = samples
        .par_iter()
        .map(|s| {
            let k = index.get(code_of_cell(cell_of(s.pos, d)));
            k.expect("a sample's cell")
        })
        .collect();
    std::array::from_fn(|v| at.par_iter().map(|&k| medians[k][v]).collect())
}

/// Lowers each sample's splat depth as far as its local noise needs (stage 2b) and says what
/// it found. `max_depth` is the tree's depth `D`.
pub fn adapt(
    samples: &[Sample],
    density: &Density,
    depths: &mut [DepthAndArea],
    max_depth: u32,
) -> NoiseSummary {
    adapt_at(samples, density, depths, max_depth, None)
}

/// Each sample's measured noise and the depth it was measured at, `None` where it could not
/// be measured ([`measure`]): the costly half of [`adapt_at`], which a slab run measures once
/// per slab and keeps.
pub type Measured = Vec<Option<MeasuredNoise>>;

/// One sample's noise as [`measure`] found it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct MeasuredNoise {
    /// The noise σ (unit-cube units), 0 where the samples do not resolve the surface.
    pub sigma: f64,
    /// The depth of the plane it was measured over.
    pub depth: u32,
    /// The residual of the quadratic height field fitted over the plane one depth coarser,
    /// over the residual of the measuring depth's fit (before resolution zeroed `sigma`);
    /// infinite where that coarser neighbourhood is not flat or its fit not determined.
    pub coarser: f64,
}

/// The depths at which the samples `keep` picks had their noise measured (`measured`, from
/// [`measure`]), as a histogram (entry `d` counts the samples measured at depth `d`): slabs
/// add theirs, so that every slab smooths at the depth [`smoothing_depth`] finds for the
/// whole cloud.
pub fn measured_depths(
    samples: &[Sample],
    measured: &[Option<MeasuredNoise>],
    max_depth: u32,
    keep: impl Fn(&Sample) -> bool,
) -> Vec<u64> {
    let mut histogram = vec![0u64; max_depth as usize + 1];
    for (s, m) in samples.iter().zip(measured) {
        if let Some(m) = m {
            if keep(s) {
                histogram[m.depth as usize] += 1;
            }
        }
    }
    histogram
}

/// The depth the noise is smoothed at: one above the median depth of measurement, from the
/// histogram of [`measured_depths`].
pub fn smoothing_depth(histogram: &[u64], max_depth: u32) -> u32 {
    let total: u64 = histogram.iter().sum();
    let mut seen = 0u64;
    let median = histogram.iter().enumerate().find_map(|(d, &c)| {
        seen += c;
        (total > 0 && seen > total / 2).then_some(d as u32)
    });
    median.unwrap_or(max_depth).saturating_sub(1).max(1)
}

/// As [`adapt`], smoothing at `smooth_depth` when given (slabs), else at the depth this
/// cloud's own measurements give.
pub fn adapt_at(
    samples: &[Sample],
    density: &Density,
    depths: &mut [DepthAndArea],
    max_depth: u32,
    smooth_depth: Option<u32>,
) -> NoiseSummary {
    if samples.is_empty() {
        return NoiseSummary::default();
    }
    let measured = measure(samples, max_depth);
    adapt_measured(samples, density, depths, &measured, max_depth, smooth_depth)
}

/// As [`adapt_at`], with the noise already measured (`measured`, from [`measure`]).
pub fn adapt_measured(
    samples: &[Sample],
    density: &Density,
    depths: &mut [DepthAndArea],
    measured: &[Option<MeasuredNoise>],
    max_depth: u32,
    smooth_depth: Option<u32>,
) -> NoiseSummary {
    let n = samples.len();
    if n == 0 {
        return NoiseSummary::default();
    }
    let raw: Vec<f64> = measured
        .iter()
        .map(|m| m.map_or(f64::NAN, |m| m.sigma))
        .collect();
    let mut at: Vec<u32> = measured.iter().filter_map(|m| m.map(|m| m.depth)).collect();
    let smooth_depth = smooth_depth.unwrap_or_else(|| {
        median_by(&mut at, u32::cmp)
            .unwrap_or(max_depth)
            .saturating_sub(1)
            .max(1)
    });
    // The shape's ratio counts only where the noise does; where no noisy sample is near,
    // the shape is not known to be a quadratic.
    let coarser: Vec<f64> = measured
        .iter()
        .map(|m| m.filter(|m| m.sigma > 0.0).map_or(f64::NAN, |m| m.coarser))
        .collect();
    let empty = [0.0, f64::INFINITY];
    let [sigma, coarser] = smooth(samples, [&raw, &coarser], smooth_depth, empty);
    let [sigma, coarser] = smooth(
        samples,
        [&sigma, &coarser],
        smooth_depth.saturating_sub(SECOND_SMOOTHING).max(1),
        empty,
    );
    let caps = caps(&coarser, depths);
    let mut sigmas: Vec<f64> = raw.into_iter().filter(|s| !s.is_nan()).collect();
    let median = median_by(&mut sigmas, f64::total_cmp).unwrap_or(0.0);
    let lowered: Vec<f64> = depths
        .par_iter_mut()
        .zip(samples.par_iter().zip(sigma.par_iter().zip(&caps)))
        .map(|(q, (sample, (&s, &cap)))| {
            let factor = samples_per_node_factor(s, q.depth.min(f64::from(max_depth)), cap.splat);
            if factor <= 1.0 {
                return 0.0;
            }
            let scaled = density.query_scaled(sample.pos, factor);
            let drop = (q.depth - scaled.depth).max(0.0);
            *q = DepthAndArea {
                screen: factor.min(cap.screen).powf(-SCREEN_POWER),
                screen_depth: screen_depth(
                    q.depth,
                    s,
                    density.samples_per_node(),
                    cap.averaging,
                    max_depth,
                ),
                ..scaled
            };
            drop
        })
        .collect();
    let adapted = lowered.iter().filter(|&&l| l > ADAPTED).count();
    NoiseSummary {
        median,
        median_cells: median * f64::from(max_depth).exp2(),
        measured: at.len() as f64 / n as f64,
        adapted: adapted as f64 / n as f64,
        mean_lowering: if adapted > 0 {
            lowered.iter().filter(|&&l| l > ADAPTED).sum::<f64>() / adapted as f64
        } else {
            0.0
        },
    }
}

/// A sample's caps on the multiplication of its samples per node ([`caps`]).
#[derive(Debug, Clone, Copy, PartialEq)]
struct Cap {
    /// On the factor its splat depth and area are queried at.
    splat: f64,
    /// On the factor its screening is lowered by.
    screen: f64,
    /// The noise its screening clusters' means may keep, in widths of their cells
    /// ([`screen_depth`]).
    averaging: f64,
}

/// Each sample's caps, from its smoothed [`MeasuredNoise::coarser`] and its density depth
/// (`depths`, before the adaptation): [`SMOOTH_MAX_FACTOR`] for both where its shape is still
/// a quadratic one depth coarser than its noise was measured at (at most
/// [`STILL_QUADRATIC`]); elsewhere [`dense_cap`] on the splat and [`MAX_FACTOR`] on the
/// screening.
fn caps(coarser: &[f64], depths: &[DepthAndArea]) -> Vec<Cap> {
    coarser
        .par_iter()
        .zip(depths)
        .map(|(&c, q)| {
            if c <= STILL_QUADRATIC {
                Cap {
                    splat: SMOOTH_MAX_FACTOR,
                    screen: SMOOTH_MAX_FACTOR,
                    averaging: SMOOTH_SCREEN_AVERAGING,
                }
            } else {
                Cap {
                    splat: dense_cap(q.depth),
                    screen: MAX_FACTOR,
                    averaging: SCREEN_AVERAGING,
                }
            }
        })
        .collect()
}

/// The cap on the splat's factor of a sample whose shape is not known to be smooth, at
/// density depth `d`: [`MAX_FACTOR`] up to [`DENSE_FROM`], and past it a further
/// [`DENSE_LEVELS`] of a level of lowering for each level of density depth (see the module
/// docs, *Denser clouds*).
fn dense_cap(d: f64) -> f64 {
    MAX_FACTOR * 4f64.powf(DENSE_LEVELS * (d - DENSE_FROM).max(0.0))
}

/// How many times its density's samples per node a sample of noise `σ` is splatted with,
/// where the density gives it depth `d` (cells of width `h = 2^-d`): `1 + (κσ/h)²`, at most
/// `cap` ([`caps`]); 1 for a clean sample.
fn samples_per_node_factor(sigma: f64, d: f64, cap: f64) -> f64 {
    let r = CELLS_PER_NOISE * sigma * d.exp2();
    (1.0 + r * r).min(cap)
}

/// The finest depth whose screening clusters take a noisy sample of noise `σ` whose density
/// gives it depth `d` at `spn` samples per node ([`DepthAndArea::screen_depth`]): the finest
/// depth at which a cluster averages enough samples that the noise left in its mean position
/// is at most `averaging` ([`SCREEN_AVERAGING`], or [`SMOOTH_SCREEN_AVERAGING`] on smooth
/// shapes) of its cell's width. A cluster at depth `d'` holds about `spn · 4^(d − d')`
/// samples, whose mean is off by `σ / √(spn · 4^(d − d'))`; that is at most `a 2^-d'` for
/// `d' ≤ (d + log2(a √spn / σ)) / 2`. [`ALL_DEPTHS`] where that is the tree's depth
/// `max_depth` or finer (see the module docs, *Screening depth*).
fn screen_depth(d: f64, sigma: f64, spn: f64, averaging: f64, max_depth: u32) -> u32 {
    let finest = 0.5 * (d + (averaging * spn.sqrt() / sigma).log2());
    if finest.is_nan() || finest >= f64::from(max_depth) {
        return ALL_DEPTHS;
    }
    finest.floor().max(0.0) as u32
}

/// The noise a noisy sample's screening clusters may keep in their mean positions, in widths
/// of their cells ([`screen_depth`]).
const SCREEN_AVERAGING: f64 = 1.0;

/// [`SCREEN_AVERAGING`] where the shape is still a quadratic one depth coarser (the samples
/// whose splat may go to [`SMOOTH_MAX_FACTOR`]): there coarser screening loses no shape.
const SMOOTH_SCREEN_AVERAGING: f64 = 0.5;

/// A noisy sample's screening keeps `factor^-SCREEN_POWER` of its weight, where `factor` is
/// the multiplication of its samples per node ([`samples_per_node_factor`]; see the module
/// docs).
const SCREEN_POWER: f64 = 0.5;

/// A sample counts as adapted when its depth was lowered by more than this (in levels).
const ADAPTED: f64 = 0.05;

/// The median of `v` (reordered), `None` when it is empty.
fn median_by<T: Copy>(v: &mut [T], cmp: impl FnMut(&T, &T) -> std::cmp::Ordering) -> Option<T> {
    if v.is_empty() {
        return None;
    }
    let m = v.len() / 2;
    Some(*v.select_nth_unstable_by(m, cmp).1)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The noise left in the mean position of a cluster at depth `k`, which holds about
    /// `spn · 4^(d − k)` samples of noise `sigma` whose density gives them depth `d`.
    fn left_in_cluster(sigma: f64, d: f64, spn: f64, k: u32) -> f64 {
        sigma / (spn * 4f64.powf(d - f64::from(k))).sqrt()
    }

    /// The width of a cell at depth `k`.
    fn cell(k: u32) -> f64 {
        0.5f64.powi(k as i32)
    }

    #[test]
    fn a_noisy_sample_is_screened_down_to_the_finest_depth_whose_clusters_average_its_noise() {
        // Noise of 0.2 to 2 % of the cube at the density depths of 100,000 to 1,000,000
        // points, and a cloud at 5 samples per node.
        for (sigma, d, spn) in [
            (2e-3, 7.6, 1.5),
            (5e-3, 7.6, 1.5),
            (8e-3, 7.6, 1.5),
            (5e-3, 9.2, 1.5),
            (2e-2, 6.5, 1.5),
            (5e-3, 7.6, 5.0),
        ] {
            let k = screen_depth(d, sigma, spn, SCREEN_AVERAGING, 12);
            assert!(k < 12, "σ {sigma}, depth {d}: {k}");
            let tolerance = 1.0 + 1e-12;
            assert!(
                left_in_cluster(sigma, d, spn, k) <= tolerance * SCREEN_AVERAGING * cell(k),
                "σ {sigma}, depth {d}: at depth {k} the clusters keep too much of the noise"
            );
            assert!(
                left_in_cluster(sigma, d, spn, k + 1) > SCREEN_AVERAGING * cell(k + 1),
                "σ {sigma}, depth {d}: depth {} would average it too",
                k + 1
            );
        }
    }

    #[test]
    fn more_noise_is_screened_no_finer_and_faint_noise_at_every_depth() {
        let mut last = ALL_DEPTHS;
        for i in 0..60 {
            let sigma = 1e-6 * 1.3f64.powi(i);
            let k = screen_depth(7.6, sigma, 1.5, SCREEN_AVERAGING, 10);
            assert!(k <= last, "σ {sigma}: depth {k} after {last}");
            last = k;
        }
        assert!(last < 5, "{last}");
        // Noise the clusters of the tree's own depth already average is screened everywhere.
        assert_eq!(
            screen_depth(7.6, 1e-6, 1.5, SCREEN_AVERAGING, 10),
            ALL_DEPTHS
        );
        assert_eq!(
            screen_depth(9.2, 1e-3, 1.5, SCREEN_AVERAGING, 8),
            ALL_DEPTHS
        );
        // A smooth shape's samples are screened no finer than the others'.
        for sigma in [1e-3, 4e-3, 1.6e-2] {
            let smooth = screen_depth(7.6, sigma, 1.5, SMOOTH_SCREEN_AVERAGING, 10);
            assert!(smooth <= screen_depth(7.6, sigma, 1.5, SCREEN_AVERAGING, 10));
        }
    }
}
