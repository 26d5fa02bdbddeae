//! The work of each stage (issue 20): the bytes it must move at the least and the
//! floating-point operations it does, from the sizes the run knows, so that a stage's time can
//! be read against the machine's memory bandwidth (`bench/floor/run.py`).
//!
//! This is a *floor* model of the traffic. Its assumptions, for every stage:
//!
//! - every array a stage reads is read once and every array it writes is written once, at
//!   its stored size; data read again while still in cache (a stencil's neighbours, a tree
//!   level's neighbour table shared by eight siblings) is not counted again, nor are
//!   write-allocate reads, temporary vectors, sorts' extra passes or the arrays' zeroing;
//! - the octree is read through its neighbour table and keys: `NODE_TABLE_BYTES` per node
//!   (a brood's 27 neighbour indices and its key, shared by its 8 nodes);
//! - an iterative stage moves its working set once per iteration (a Gauss–Seidel sweep reads
//!   the right-hand side, reads and writes the coefficients, and reads the level's clusters);
//! - the input file and the output file count at their size on disk (in the page cache).
//!
//! The flops are counted from the loops, for an interior node (the stencil's entries, the
//! clusters around a node), not measured; boundary rows, comparisons and integer work are
//! left out. They are within a small factor of what runs, which is enough to tell whether a
//! stage could be limited by arithmetic rather than memory.
//!
//! Each function below is named after its stage (the names `-v` prints) and says its formula.

use std::time::Duration;

/// What one stage moves and computes, by the floor model of this module.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Work {
    /// Bytes the stage must move between memory and the cores at the least.
    pub bytes: f64,
    /// Floating-point operations (an add or a multiply each; a fused multiply-add is two).
    pub flops: f64,
}

impl Work {
    fn new(bytes: f64, flops: f64) -> Self {
        Work { bytes, flops }
    }

    /// The bandwidth this work implies when it takes `time` (GB/s, 10⁹ bytes per second).
    pub fn rate_gbs(&self, time: Duration) -> f64 {
        self.bytes / time.as_secs_f64().max(1e-9) / 1e9
    }
}

impl std::ops::Add for Work {
    type Output = Work;
    fn add(self, o: Work) -> Work {
        Work::new(self.bytes + o.bytes, self.flops + o.flops)
    }
}

impl std::iter::Sum for Work {
    fn sum<I: Iterator<Item = Work>>(it: I) -> Work {
        it.fold(Work::default(), |a, b| a + b)
    }
}

/// The sizes of a run that the model reads.
#[derive(Debug, Clone, Default)]
pub struct Sizes {
    /// Points given to the pipeline.
    pub points: usize,
    /// Samples after merging.
    pub samples: usize,
    /// Octree nodes per unit depth (index 0 is the unit cube).
    pub nodes_per_depth: Vec<usize>,
    /// Screening clusters per unit depth (same indexing; 0 below the base depth).
    pub clusters_per_depth: Vec<usize>,
    /// The depth solved by conjugate gradients.
    pub base_depth: u32,
    /// B-spline degree of χ, 1 or 2.
    pub degree: u8,
    /// Gauss–Seidel sweeps per depth.
    pub iters: u32,
    /// The sweeps of the deepest depth's first relaxation (`Params::first_deepest_iters`).
    pub first_deepest_iters: u32,
    /// Depths each sample is splatted into (1, or 2 with `two_level_splat`).
    pub splat_levels: usize,
    /// Vertices and triangles of the extracted mesh.
    pub vertices: usize,
    /// See `vertices`.
    pub faces: usize,
}

impl Sizes {
    fn nodes(&self, d: u32) -> f64 {
        self.nodes_per_depth.get(d as usize).copied().unwrap_or(0) as f64
    }

    fn clusters(&self, d: u32) -> f64 {
        self.clusters_per_depth
            .get(d as usize)
            .copied()
            .unwrap_or(0) as f64
    }

    fn max_depth(&self) -> u32 {
        self.nodes_per_depth.len().saturating_sub(1) as u32
    }

    /// The unknowns' depths, base to finest.
    fn solved(&self) -> std::ops::RangeInclusive<u32> {
        self.base_depth..=self.max_depth()
    }

    fn n(&self) -> f64 {
        self.points as f64
    }

    fn s(&self) -> f64 {
        self.samples as f64
    }

    /// `k + 1`: B-splines of one axis nonzero at a point.
    fn k1(&self) -> f64 {
        f64::from(self.degree) + 1.0
    }

    /// The stiffness stencil's entries, `(2k + 1)³`: 27 for degree 1, 125 for degree 2.
    pub fn stencil(&self) -> f64 {
        (2.0 * f64::from(self.degree) + 1.0).powi(3)
    }

    /// Functions nonzero at a point, `(k + 1)³`: the functions a cluster touches.
    fn support(&self) -> f64 {
        self.k1().powi(3)
    }
}

// Stored sizes, in bytes, of what the stages read and write.
/// A point's position and normal as read (`[f64; 3]` twice).
const CLOUD_POINT: f64 = 48.0;
/// A unit-cube point: position, normal, weight (`prepare::UnitPoint`).
const UNIT_POINT: f64 = 56.0;
/// A sample: position, weight, normal (`density::Sample`).
const SAMPLE: f64 = 56.0;
/// A sample's estimated depth and area (`density::DepthAndArea`).
const DEPTH_AREA: f64 = 16.0;
/// A sample's splat depths and fractions (`tree::Splat`).
const SPLAT: f64 = 32.0;
/// A node's share of its level's tables: child index (4) and, per brood of 8, the parent (4),
/// the key (12) and the 27 neighbours (108).
const NODE_TREE: f64 = 4.0 + (4.0 + 12.0 + 108.0) / 8.0;
/// A node's share of what a stencil loop reads of the tree: its brood's key and neighbours.
const NODE_TABLE_BYTES: f64 = (12.0 + 108.0) / 8.0;
/// A cluster: node (4), position (24), ω (8), first index (12), basis values (36).
const CLUSTER: f64 = 84.0;
/// A vertex (`[f64; 3]`) and a triangle (`[u32; 3]`) of the mesh.
const VERTEX: f64 = 24.0;
const TRIANGLE: f64 = 12.0;
/// V's coefficients at a node (`[f32; 3]`).
const V: f64 = 12.0;

/// The work of the stage `-v` lists as `name` (a solver part with its two-space indent
/// too); `None` for a stage without a model: the noise adaptation, the grid, the trimming,
/// the solver's further cycles, and "solving", which is the sum of its parts ([`of_stages`]).
/// Reading and writing are the front end's: [`reading`], [`writing`].
pub fn of_stage(name: &str, s: &Sizes) -> Option<Work> {
    let name = name.trim();
    Some(match name {
        "preparing points" => preparing_points(s),
        "density" => density(s),
        "orientation" => orientation(s),
        "octree" => octree(s),
        "splatting" => splatting(s),
        "clusters" => clusters(s),
        "divergence constraints" => divergence_constraints(s),
        "iso-value" => iso_value(s),
        "extraction" => extraction(s),
        "fragments" => fragments(s),
        "checking the mesh" => checking_the_mesh(s),
        _ => {
            let (depth, part) = name.strip_prefix("depth ")?.split_once(": ")?;
            let d: u32 = depth.parse().ok()?;
            match part {
                "conjugate gradients" => conjugate_gradients(s, d),
                "right-hand side" => right_hand_side(s, d),
                "right-hand sides" => right_hand_sides(s, d),
                "Gauss-Seidel" => gauss_seidel(s, d),
                "residual" => residual(s, d),
                "prolongation" => prolongation(s, d),
                _ => return None,
            }
        }
    })
}

/// The work of every stage in `stages`, in order. "solving" gets the sum of the parts listed
/// after it (indented), those without a model left out.
pub fn of_stages<'a>(stages: impl IntoIterator<Item = &'a str>, s: &Sizes) -> Vec<Option<Work>> {
    let names: Vec<&str> = stages.into_iter().collect();
    names
        .iter()
        .enumerate()
        .map(|(k, name)| {
            if *name != "solving" {
                return of_stage(name, s);
            }
            let parts = names[k + 1..].iter().take_while(|n| n.starts_with("  "));
            Some(parts.filter_map(|n| of_stage(n, s)).sum())
        })
        .collect()
}

/// Reading the input: the file (`file_bytes`) read, the positions and normals written as
/// `f64`. No flops are counted (parsing is integer work).
pub fn reading(file_bytes: u64, points: usize) -> Work {
    Work::new(file_bytes as f64 + CLOUD_POINT * points as f64, 0.0)
}

/// Writing the mesh: its vertices and triangles read, the file (`file_bytes`) written.
pub fn writing(file_bytes: u64, vertices: usize, faces: usize) -> Work {
    Work::new(
        file_bytes as f64 + VERTEX * vertices as f64 + TRIANGLE * faces as f64,
        0.0,
    )
}

/// Stage 1: each point read (48 B) and its unit-cube copy written (56 B); 16 flops a point
/// (the affine map, 6; the normal's length and division, 9; the weight, 1).
fn preparing_points(s: &Sizes) -> Work {
    Work::new(s.n() * (CLOUD_POINT + UNIT_POINT), 16.0 * s.n())
}

/// Stage 2: the points read once (56 B) while merged, each sample written (56 B) and its depth
/// and area (16 B). Flops: 14 a point (weighted sums of position and normal); per sample 10 to
/// normalise and, for the density estimate's build and query, two passes over the 27 quadratic
/// weights around it (27 products and 27 sums each, plus 9 × 3 for the 1-D weights).
fn density(s: &Sizes) -> Work {
    let per_sample = 10.0 + 2.0 * (27.0 * 2.0 + 27.0);
    Work::new(
        s.n() * UNIT_POINT + s.s() * (SAMPLE + DEPTH_AREA),
        14.0 * s.n() + per_sample * s.s(),
    )
}

/// Stage 2a: the samples read once (56 B); 9 flops each (a normal added to its cell's sum,
/// and the dot product with the sum).
fn orientation(s: &Sizes) -> Work {
    Work::new(s.s() * SAMPLE, 9.0 * s.s())
}

/// Stage 3: the samples and their depths read (72 B), each sample's splat written (32 B), the
/// tree's tables written (`NODE_TREE`, 19.5 B a node). 10 flops a sample (its splat depths
/// and fractions); building the tree is integer work.
fn octree(s: &Sizes) -> Work {
    let nodes: f64 = s.nodes_per_depth.iter().sum::<usize>() as f64;
    Work::new(
        s.s() * (SAMPLE + DEPTH_AREA + SPLAT) + nodes * NODE_TREE,
        10.0 * s.s(),
    )
}

/// Stage 4: the samples, depths and splats read (104 B), V written at every node from the base
/// depth down (12 B). Flops per sample and splat depth: 27 for the 1-D quadratic weights and 9
/// for each of the 27 nodes around it (the weight's product, the scale, three multiply-adds).
fn splatting(s: &Sizes) -> Work {
    let v_nodes: f64 = s.solved().map(|d| s.nodes(d)).sum();
    Work::new(
        s.s() * (SAMPLE + DEPTH_AREA + SPLAT) + v_nodes * V,
        s.s() * s.splat_levels as f64 * (27.0 + 27.0 * 9.0),
    )
}

/// Stage 5: positions and weights read (32 B a sample), each sample's deepest node written
/// (8 B), each cluster written once per depth (`CLUSTER`, 84 B). Flops: 8 a sample and depth
/// (the weighted position sums) and per cluster 10 for each of the `3 (k + 1)` 1-D basis
/// values.
fn clusters(s: &Sizes) -> Work {
    let depths = s.solved().count() as f64;
    let c: f64 = s.solved().map(|d| s.clusters(d)).sum();
    Work::new(
        s.s() * (32.0 + 8.0) + c * CLUSTER,
        8.0 * s.s() * depths + c * 30.0 * s.k1(),
    )
}

/// The divergence constraints, fine to coarse: at every node from the base depth down, V read
/// (12 B), the tree read (`NODE_TABLE_BYTES`), the constraint written (4 B) and the finer
/// depth's sum handed up (8 B written, read again by the coarser depth). Flops: the 125-entry
/// window of V's degree-2 functions, three multiply-adds each (750 a node), and the finer
/// depth's sum restricted through `(k + 2)³` two-scale weights (2 each).
fn divergence_constraints(s: &Sizes) -> Work {
    let mut w = Work::default();
    for d in s.solved() {
        let n = s.nodes(d);
        let finer = if d < s.max_depth() {
            s.nodes(d + 1)
        } else {
            0.0
        };
        w = w + Work::new(
            n * (V + NODE_TABLE_BYTES + 4.0 + 8.0) + finer * 8.0,
            n * 750.0 + finer * 2.0 * (s.k1() + 1.0).powi(3),
        );
    }
    w
}

/// The base depth's conjugate gradients: its matrix assembled once, `(2k + 1)³` entries a row
/// of 12 B (value and column), and one matrix product with its five vectors (8 B). The number
/// of iterations is not recorded, so this is one iteration's work: the stage is small.
fn conjugate_gradients(s: &Sizes, d: u32) -> Work {
    let n = s.nodes(d);
    Work::new(
        n * (2.0 * s.stencil() * 12.0 + 5.0 * 8.0),
        n * (2.0 * s.stencil() + 10.0),
    )
}

/// Interior parent-window entries a child function couples to, averaged over the eight child
/// positions: the coarser solution's stiffness and V's divergence (`DepthTables::pnonzero`;
/// 3 or 4 per axis for degree 1, 3.5 on average; 4 for degree 2).
fn parent_window(degree: u8) -> f64 {
    if degree == 1 {
        3.5f64.powi(3)
    } else {
        64.0
    }
}

/// A depth's right-hand side: its constraint read and right-hand side written (4 B each),
/// the tree (`NODE_TABLE_BYTES`), the parent depth's cumulative solution (8 B) and V (12 B),
/// the clusters (84 B) and their coarser χ (8 B). Flops per node: four multiply-adds for each
/// parent-window entry (the solution's and V's three components); per cluster the coarser χ
/// (`(k + 1)³` functions, 4 flops each) and its `(k + 1)³` screening terms (10 each).
fn right_hand_side(s: &Sizes, d: u32) -> Work {
    let (n, parent, c) = (s.nodes(d), s.nodes(d.saturating_sub(1)), s.clusters(d));
    Work::new(
        n * (8.0 + NODE_TABLE_BYTES) + parent * (8.0 + V) + c * (CLUSTER + 8.0),
        n * 8.0 * parent_window(s.degree) + c * s.support() * 14.0,
    )
}

/// A depth's right-hand side in the first of several solver cycles, with its fixed part (the
/// constraints, V's coupling and the screening targets, which the further cycles keep) from
/// the same walk: the right-hand side's bytes plus the fixed part written (4 B); its flops
/// plus three multiply-adds per parent-window entry and two per screening term.
fn right_hand_sides(s: &Sizes, d: u32) -> Work {
    let one = right_hand_side(s, d);
    let (n, c) = (s.nodes(d), s.clusters(d));
    Work::new(
        one.bytes + n * 4.0,
        one.flops + n * 6.0 * parent_window(s.degree) + c * s.support() * 2.0,
    )
}

/// The residual a depth's relaxation leaves, with `--residuals`: one sweep's reads without its writes
/// (right-hand side and coefficients, 4 B each; the tree; the clusters and their χ, computed
/// first, 84 + 8 B), and a sweep's flops plus 4 a node for the norms.
fn residual(s: &Sizes, d: u32) -> Work {
    let (n, c) = (s.nodes(d), s.clusters(d));
    Work::new(
        n * (8.0 + NODE_TABLE_BYTES + 8.0) + c * (CLUSTER + 8.0 + 8.0),
        n * (2.0 * s.stencil() + 8.0) + c * s.support() * 8.0,
    )
}

/// A depth's Gauss–Seidel sweeps, `iters` of them: per sweep the right-hand side read (4 B),
/// the coefficients read and written (4 B each), the tree (`NODE_TABLE_BYTES`), each cluster's
/// ω, first index and basis values (56 B) and its running χ read and written (8 B each); before
/// the sweeps, the clusters' χ once (a cluster read, χ written). Flops per sweep: a multiply-add
/// per stencil entry and 4 for the update, a node; 10 per cluster for each of the `(k + 1)³`
/// functions it touches.
fn gauss_seidel(s: &Sizes, d: u32) -> Work {
    let (n, c) = (s.nodes(d), s.clusters(d));
    // The profile's per-depth laps are the first pass's (the deepest depth's makes fewer
    // sweeps when more cycles follow); later cycles are laps of their own.
    let sweeps = f64::from(if d as usize + 1 == s.nodes_per_depth.len() {
        s.first_deepest_iters
    } else {
        s.iters
    });
    let sweep = Work::new(
        n * (12.0 + NODE_TABLE_BYTES) + c * (56.0 + 16.0),
        n * (2.0 * s.stencil() + 4.0) + c * s.support() * 10.0,
    );
    let start = Work::new(c * (CLUSTER + 8.0), c * s.support() * 4.0);
    Work::new(sweep.bytes * sweeps, sweep.flops * sweeps) + start
}

/// A depth's prolongation (none at the finest depth, which hands nothing on): the parent
/// depth's cumulative solution (8 B) and V (12 B) read, the depth's coefficients (4 B) and own
/// V (12 B) read, the tree (`NODE_TABLE_BYTES`), the cumulative solution written in double and
/// single precision (12 B) and the cumulative V (12 B). Flops per node: 2 per two-scale weight,
/// `((k + 2) / 2)³` of them for χ and 8 for each of V's three components.
fn prolongation(s: &Sizes, d: u32) -> Work {
    if d >= s.max_depth() {
        return Work::default();
    }
    let (n, parent) = (s.nodes(d), s.nodes(d.saturating_sub(1)));
    let weights = ((s.k1() + 1.0) / 2.0).powi(3);
    Work::new(
        parent * (8.0 + V) + n * (4.0 + V + NODE_TABLE_BYTES + 12.0 + V),
        n * (2.0 * weights + 3.0 * 2.0 * 8.0),
    )
}

/// Flops of χ at a point: two windows of `(k + 1)³` functions (the parent's cumulative and the
/// leaf's own coefficients), 4 flops each, and their `2 · 3 (k + 1)` 1-D values, 6 each.
fn value_flops(s: &Sizes) -> f64 {
    2.0 * s.support() * 4.0 + 2.0 * 3.0 * s.k1() * 6.0
}

/// Flops of χ and ∇χ at a point: four sums instead of one.
fn value_grad_flops(s: &Sizes) -> f64 {
    4.0 * value_flops(s)
}

/// Stage 7: positions and weights read (32 B a sample) and the coefficients of the two finest
/// depths, where the samples' leaves are (4 B each, and the cumulative 4 B at the depth above
/// the finest); χ at each sample and 2 flops for the weighted sum.
fn iso_value(s: &Sizes) -> Work {
    let dm = s.max_depth();
    Work::new(
        s.s() * 32.0 + s.nodes(dm) * 4.0 + s.nodes(dm.saturating_sub(1)) * 8.0,
        s.s() * (value_flops(s) + 2.0),
    )
}

/// Stage 8: the coefficients (8 B: own and cumulative) and the child table (4 B) of every node
/// from the base depth down read, the mesh written (24 B a vertex, 12 B a triangle). Flops: χ
/// at one corner per finest node (the leaves' corners, shared) and χ with ∇χ at the two ends of
/// each vertex's edge; the triangulation is integer work.
fn extraction(s: &Sizes) -> Work {
    let nodes: f64 = s.solved().map(|d| s.nodes(d)).sum();
    let (v, f) = (s.vertices as f64, s.faces as f64);
    Work::new(
        nodes * 12.0 + v * VERTEX + f * TRIANGLE,
        s.nodes(s.max_depth()) * value_flops(s) + v * 2.0 * value_grad_flops(s),
    )
}

/// Stage 9 (with the noise adaptation): the mesh read (24 B a vertex, 12 B a triangle), each
/// triangle's piece written (4 B); 30 flops a triangle (its area).
fn fragments(s: &Sizes) -> Work {
    let (v, f) = (s.vertices as f64, s.faces as f64);
    Work::new(v * VERTEX + f * (TRIANGLE + 4.0), 30.0 * f)
}

/// Stage 10: the mesh read (24 B a vertex, 12 B a triangle) and its 3 edges a triangle
/// written and read once by the sort (16 B each way: two vertex indices and the triangle).
/// Flops: 30 a triangle (its area and signed volume).
fn checking_the_mesh(s: &Sizes) -> Work {
    let (v, f) = (s.vertices as f64, s.faces as f64);
    Work::new(v * VERTEX + f * TRIANGLE + f * 3.0 * 32.0, 30.0 * f)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::bspline::{Basis, Boundary, Degree};
    use crate::system::DepthTables;

    fn sizes(degree: u8) -> Sizes {
        Sizes {
            points: 1_000_000,
            samples: 900_000,
            nodes_per_depth: vec![1, 8, 64, 512, 4096, 32768, 100_000, 400_000, 1_600_000],
            clusters_per_depth: vec![0, 0, 0, 0, 0, 20_000, 80_000, 300_000, 800_000],
            base_depth: 5,
            degree,
            iters: 8,
            first_deepest_iters: 8,
            splat_levels: 1,
            vertices: 500_000,
            faces: 1_000_000,
        }
    }

    #[test]
    fn a_stage_with_a_model_has_positive_work() {
        let s = sizes(1);
        for name in [
            "preparing points",
            "density",
            "orientation",
            "octree",
            "splatting",
            "clusters",
            "  divergence constraints",
            "  depth 5: conjugate gradients",
            "  depth 7: right-hand side",
            "  depth 7: right-hand sides",
            "  depth 7: Gauss-Seidel",
            "  depth 7: residual",
            "  depth 7: prolongation",
            "iso-value",
            "extraction",
            "fragments",
            "checking the mesh",
        ] {
            let w = of_stage(name, &s).unwrap_or_else(|| panic!("no model for {name}"));
            assert!(w.bytes > 0.0 && w.flops > 0.0, "{name}: {w:?}");
        }
        assert_eq!(of_stage("trimming", &s), None);
        assert_eq!(of_stage("solving", &s), None);
        assert_eq!(of_stage("  depth 7: something else", &s), None);
        // The finest depth hands nothing on.
        assert_eq!(
            of_stage("  depth 8: prolongation", &s),
            Some(Work::default())
        );
    }

    #[test]
    fn the_splat_stage_moves_twice_the_sample_bytes_for_twice_the_samples() {
        let one = Sizes {
            nodes_per_depth: Vec::new(),
            ..sizes(1)
        };
        let two = Sizes {
            samples: 2 * one.samples,
            ..one.clone()
        };
        let (a, b) = (splatting(&one), splatting(&two));
        assert_eq!(b.bytes, 2.0 * a.bytes);
        assert_eq!(b.flops, 2.0 * a.flops);
        // With the tree, the sample part alone doubles.
        let (a, b) = (
            splatting(&sizes(1)),
            splatting(&Sizes {
                samples: 1_800_000,
                ..sizes(1)
            }),
        );
        assert!(b.bytes > a.bytes && b.bytes < 2.0 * a.bytes);
    }

    #[test]
    fn degree_2_sweeps_do_more_than_degree_1_on_the_same_tree() {
        let (one, two) = (sizes(1), sizes(2));
        assert_eq!((one.stencil(), two.stencil()), (27.0, 125.0));
        for name in ["  depth 8: Gauss-Seidel", "  depth 8: right-hand side"] {
            let (a, b) = (of_stage(name, &one).unwrap(), of_stage(name, &two).unwrap());
            assert!(b.flops > a.flops, "{name}");
            assert!(b.bytes >= a.bytes, "{name}");
        }
    }

    #[test]
    fn the_solving_stage_is_the_sum_of_its_parts() {
        let s = sizes(2);
        let parts: Vec<String> = std::iter::once("  divergence constraints".to_string())
            .chain(std::iter::once(
                "  depth 5: conjugate gradients".to_string(),
            ))
            .chain((6..=8).flat_map(|d| {
                ["right-hand side", "Gauss-Seidel", "prolongation"]
                    .map(|p| format!("  depth {d}: {p}"))
            }))
            .chain(std::iter::once("  cycle 2: vcycle".to_string()))
            .collect();
        let names: Vec<&str> = ["clusters", "solving"]
            .into_iter()
            .chain(parts.iter().map(String::as_str))
            .chain(["iso-value"])
            .collect();
        let work = of_stages(names.iter().copied(), &s);
        let sum: Work = work[2..work.len() - 1].iter().flatten().copied().sum();
        assert_eq!(work[1], Some(sum));
        assert_eq!(work[0], of_stage("clusters", &s));
        assert_eq!(work[work.len() - 1], of_stage("iso-value", &s));
    }

    #[test]
    fn the_parent_window_is_the_tables_nonzero_entries() {
        for degree in [Degree::Linear, Degree::Quadratic] {
            let fem = Basis::new(degree, Boundary::Neumann);
            let vb = Basis::new(Degree::Quadratic, Boundary::Neumann.derivative());
            let tab = DepthTables::new(fem, vb, 6);
            let mean = tab.pnonzero.iter().map(|p| p.len()).sum::<usize>() as f64 / 8.0;
            assert_eq!(mean, parent_window(degree.get()), "degree {degree}");
        }
    }
}
