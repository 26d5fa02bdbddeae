//! Unit tests of the solver: conjugate gradients on systems with a known solution, and the
//! solver's own operators and sweeps on the system of a small reconstruction.

use super::*;
use crate::bspline::{Boundary, Degree};
use crate::pipeline::{density, prepare, splat, system, tree};
use crate::{Params, PointCloud};

/// `f` run on a pool of `threads` threads.
fn with_threads<T: Send>(threads: usize, f: impl FnOnce() -> T + Send) -> T {
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build()
        .unwrap()
        .install(f)
}

/// A fixed pseudo-random vector in [−1, 1).
pub(super) fn pseudo_random(n: usize, seed: u64) -> Vec<f64> {
    let mut s = seed;
    (0..n)
        .map(|_| {
            s ^= s << 13;
            s ^= s >> 7;
            s ^= s << 17;
            2.0 * ((s >> 11) as f64 / (1u64 << 53) as f64) - 1.0
        })
        .collect()
}

fn norm(a: &[f64]) -> f64 {
    a.iter().map(|x| x * x).sum::<f64>().sqrt()
}

fn sub(a: &[f64], b: &[f64]) -> Vec<f64> {
    a.iter().zip(b).map(|(x, y)| x - y).collect()
}

/// The 7-point Laplacian on an `m³` grid: with `dirichlet`, zero values outside the grid
/// (positive definite); otherwise zero flux across its faces (constants in the kernel).
/// Rows outside `valid` are zero, columns outside it are skipped. Returns `(A x, diagonal)`.
fn laplacian(m: usize, dirichlet: bool, valid: &[bool], x: &[f64]) -> (Vec<f64>, Vec<f32>) {
    let idx = |p: [usize; 3]| p[0] + m * (p[1] + m * p[2]);
    let mut y = vec![0.0; m * m * m];
    let mut diag = vec![0.0f32; m * m * m];
    for z in 0..m {
        for yy in 0..m {
            for xx in 0..m {
                let p = [xx, yy, z];
                let n = idx(p);
                if !valid[n] {
                    continue;
                }
                let mut s = 0.0;
                let mut dg = 0.0;
                for a in 0..3 {
                    for up in [false, true] {
                        let mut q = p;
                        let inside = if up { p[a] + 1 < m } else { p[a] > 0 };
                        if inside {
                            q[a] = if up { p[a] + 1 } else { p[a] - 1 };
                            dg += 1.0;
                            if valid[idx(q)] {
                                s -= x[idx(q)];
                            }
                        } else if dirichlet {
                            dg += 1.0;
                        }
                    }
                }
                y[n] = s + dg * x[n];
                diag[n] = dg as f32;
            }
        }
    }
    (y, diag)
}

#[test]
fn conjugate_gradients_solve_a_dirichlet_laplacian() {
    let m = 9;
    let valid = vec![true; m * m * m];
    let exact = pseudo_random(m * m * m, 7);
    let (b, diag) = laplacian(m, true, &valid, &exact);
    let apply = |x: &[f64]| laplacian(m, true, &valid, x).0;
    let x = conjugate_gradients(apply, &diag, &b, &valid, 1000, 1e-12);
    let err = norm(&sub(&x, &exact)) / norm(&exact);
    assert!(err < 1e-9, "relative error {err}");
}

#[test]
fn conjugate_gradients_solve_a_singular_neumann_laplacian_up_to_a_constant() {
    // Zero flux: constants are in the kernel, and the diagonal varies (faces, edges, corners),
    // so the Jacobi preconditioner is not a multiple of the identity.
    let m = 8;
    let valid = vec![true; m * m * m];
    let exact = pseudo_random(m * m * m, 11);
    let (mut b, diag) = laplacian(m, false, &valid, &exact);
    // b is in the range already; removing its (rounding-size) mean is what the solver does.
    remove_mean(&mut b, &valid);
    let apply = |x: &[f64]| laplacian(m, false, &valid, x).0;
    let x = conjugate_gradients(apply, &diag, &b, &valid, 1000, 1e-12);
    let centred = |v: &[f64]| {
        let mean = v.iter().sum::<f64>() / v.len() as f64;
        v.iter().map(|x| x - mean).collect::<Vec<_>>()
    };
    let err = norm(&sub(&centred(&x), &centred(&exact))) / norm(&centred(&exact));
    assert!(err < 1e-9, "relative error up to a constant {err}");
    let res = norm(&sub(&laplacian(m, false, &valid, &x).0, &b)) / norm(&b);
    assert!(res < 1e-11, "relative residual {res}");
}

#[test]
fn conjugate_gradients_leave_entries_outside_the_mask_at_zero() {
    let m = 6;
    let valid: Vec<bool> = (0..m * m * m).map(|n| n % 7 != 3).collect();
    let mut exact = pseudo_random(m * m * m, 5);
    for (e, &v) in exact.iter_mut().zip(&valid) {
        if !v {
            *e = 0.0;
        }
    }
    let (b, diag) = laplacian(m, true, &valid, &exact);
    let apply = |x: &[f64]| laplacian(m, true, &valid, x).0;
    let x = conjugate_gradients(apply, &diag, &b, &valid, 1000, 1e-12);
    assert!(x.iter().zip(&valid).all(|(&x, &v)| v || x == 0.0));
    let err = norm(&sub(&x, &exact)) / norm(&exact);
    assert!(err < 1e-9, "relative error {err}");
    // A zero right-hand side is solved by zero, at once.
    let zero = vec![0.0; m * m * m];
    let apply = |_: &[f64]| -> Vec<f64> { panic!("no iteration for a zero right-hand side") };
    assert_eq!(
        conjugate_gradients(apply, &diag, &zero, &valid, 1000, 1e-12),
        zero
    );
}

#[test]
fn remove_mean_leaves_a_zero_sum_over_the_valid_entries_only() {
    let mut b = vec![1.0, 2.0, 100.0, 6.0];
    let valid = [true, true, false, true];
    remove_mean(&mut b, &valid);
    assert_eq!(b, vec![-2.0, -1.0, 100.0, 3.0]);
}

/// The system of a small reconstruction: a sphere at depth 6, levels above a base at depth 3.
pub(super) struct Fixture {
    pub(super) tree: Octree,
    pub(super) fem: Basis,
    tables: Vec<Option<DepthTables>>,
    clusters: Vec<Clusters>,
    pub(super) v: Vec<Vec<[f32; 3]>>,
    pub(super) base_level: u32,
    singular: bool,
}

impl Fixture {
    fn new(degree: Degree, boundary: Boundary, point_weight: Option<f64>) -> Self {
        Self::of(sphere(20_000), 7, degree, boundary, point_weight)
    }

    /// A sparse sphere with a small patch sampled densely enough to reach depth 7, which the
    /// rest does not: the deepest level holds a few broods under a whole level.
    fn with_deep_patch(degree: Degree, boundary: Boundary) -> Self {
        let mut cloud = sphere(5_000);
        let patch = sphere(2_000_000);
        let near_pole = (0..patch.positions.len()).filter(|&i| patch.normals[i][2] > 0.9995);
        for i in near_pole {
            cloud.positions.push(patch.positions[i]);
            cloud.normals.push(patch.normals[i]);
        }
        Self::of(cloud, 7, degree, boundary, None)
    }

    fn of(
        cloud: PointCloud,
        depth: u32,
        degree: Degree,
        boundary: Boundary,
        point_weight: Option<f64>,
    ) -> Self {
        Self::with_full_depth(cloud, depth, 3, degree, boundary, point_weight)
    }

    fn with_full_depth(
        cloud: PointCloud,
        depth: u32,
        full_depth: u32,
        degree: Degree,
        boundary: Boundary,
        point_weight: Option<f64>,
    ) -> Self {
        let params = Params {
            depth,
            full_depth,
            degree,
            boundary,
            point_weight,
            ..Params::default()
        };
        let prepared = prepare::prepare(&cloud, &params).unwrap();
        let sampled = density::sample(prepared.points, prepared.carried, &params);
        let refined = tree::build(&sampled, &params, cloud.positions.len()).unwrap();
        let field = splat::splat(&refined, &sampled, &params).unwrap();
        let tree = refined.tree;
        let fem = Basis::new(degree, boundary);
        let points = system::SamplePoints {
            positions: sampled.samples.iter().map(|s| s.pos).collect(),
            weights: sampled.samples.iter().map(|s| s.weight).collect(),
            screen_depths: Vec::new(),
        };
        let screening =
            system::screening(&tree, fem, &points, Vec::new(), 0, field.mean_area, &params);
        let base_level = params.base_depth() + DEPTH_OFFSET;
        let vb = Basis::new(Degree::Quadratic, boundary.derivative());
        let tables = (0..tree.levels.len() as u32)
            .map(|t| (t >= base_level).then(|| DepthTables::new(fem, vb, t - DEPTH_OFFSET)))
            .collect();
        Fixture {
            tree,
            fem,
            tables,
            clusters: screening.clusters,
            v: field.v,
            base_level,
            singular: params.alpha() == 0.0 && boundary != Boundary::Dirichlet,
        }
    }

    pub(super) fn problem(&self) -> Problem<'_> {
        Problem {
            tree: &self.tree,
            fem: self.fem,
            tables: &self.tables,
            clusters: &self.clusters,
            base_level: self.base_level,
            iters: 8,
            deepest_level: self.max_level(),
            first_deepest_iters: 8,
            singular: self.singular,
            solver: crate::Solver::Cascadic,
            cycles: 1,
            report: false,
            progress: &|_| {},
            gpu: None,
        }
    }

    pub(super) fn max_level(&self) -> u32 {
        self.tree.levels.len() as u32 - 1
    }
}

/// Points on a sphere (golden-angle spiral) of radius 0.3 about (0.5, 0.5, 0.5), with exact
/// outward normals.
fn sphere(n: usize) -> PointCloud {
    let ga = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let (pos, nor) = (0..n)
        .map(|i| {
            let z = 1.0 - 2.0 * (i as f64 + 0.5) / n as f64;
            let rho = (1.0 - z * z).sqrt();
            let th = ga * i as f64;
            let u = [rho * th.cos(), rho * th.sin(), z];
            (u.map(|c| 0.5 + 0.3 * c), u)
        })
        .unzip();
    PointCloud::new(pos, nor).unwrap()
}

/// The fixtures the operator tests run on: both degrees, screened and unscreened (built
/// once, shared by the tests).
pub(super) fn fixtures() -> &'static [(&'static str, Fixture)] {
    static FIXTURES: std::sync::OnceLock<Vec<(&'static str, Fixture)>> = std::sync::OnceLock::new();
    FIXTURES.get_or_init(|| {
        vec![
            (
                "degree 1 Neumann",
                Fixture::new(Degree::Linear, Boundary::Neumann, None),
            ),
            (
                "degree 2 Dirichlet",
                Fixture::new(Degree::Quadratic, Boundary::Dirichlet, None),
            ),
            (
                "degree 2 free, unscreened",
                Fixture::new(Degree::Quadratic, Boundary::Free, Some(0.0)),
            ),
        ]
    })
}

/// The level's nodes that carry a function.
fn valid_nodes(op: &Op) -> Vec<bool> {
    (0..op.level.len() as u32)
        .map(|n| op.tab.range.contains(op.index(n)))
        .collect()
}

/// A pseudo-random vector on the valid nodes, zero elsewhere.
fn masked_random(valid: &[bool], seed: u64) -> Vec<f64> {
    pseudo_random(valid.len(), seed)
        .into_iter()
        .zip(valid)
        .map(|(x, &v)| if v { x } else { 0.0 })
        .collect()
}

#[test]
fn the_assembled_matrix_is_the_matrix_free_operator_and_symmetric() {
    for (what, f) in fixtures() {
        let p = f.problem();
        for t in [f.base_level, f.max_level()] {
            let op = Op::new(&p, t);
            let valid = valid_nodes(&op);
            let a = op.assemble(&valid);
            let x = masked_random(&valid, 3);
            let (y_free, y_rows) = (op.apply(&x, &valid), a.apply(&x));
            let err = norm(&sub(&y_free, &y_rows)) / norm(&y_free);
            assert!(err < 1e-12, "{what}, level {t}: relative difference {err}");
            // Symmetric, with the diagonal of `Op::diagonal`.
            let diag = op.diagonal();
            let entry = |n: usize, m: u32| {
                let row = n * a.width..(n + 1) * a.width;
                a.cols[row.clone()]
                    .iter()
                    .zip(&a.vals[row])
                    .find(|(&c, _)| c == m)
                    .map(|(_, &v)| v)
            };
            for n in (0..valid.len()).filter(|&n| valid[n]) {
                let dg = entry(n, n as u32).expect("a diagonal entry");
                assert!(
                    (dg as f32 - diag[n]).abs() <= 1e-6 * diag[n].abs(),
                    "{what}, level {t}, node {n}: diagonal {dg} against {}",
                    diag[n]
                );
                for k in 0..a.width {
                    let m = a.cols[n * a.width + k];
                    if m == NONE {
                        continue;
                    }
                    let (v, w) = (a.vals[n * a.width + k], entry(m as usize, n as u32));
                    let w = w.expect("a symmetric pattern");
                    assert!(
                        (v - w).abs() <= 1e-12 * dg.abs(),
                        "{what}, level {t}: A[{n}][{m}] = {v}, A[{m}][{n}] = {w}"
                    );
                }
            }
        }
    }
}

/// The base matrix's rows on the grid and assembled give the assembled matrix's products to
/// the bit, on every kind of row, at the base level (complete: rows of every kind) and at the
/// finest (not complete: every row assembled), for vectors with exact zeros of both signs.
#[test]
fn the_base_matrix_applies_the_assembled_matrix_to_the_bit() {
    let mut kinds = [0usize; 4];
    for (what, f) in fixtures() {
        let p = f.problem();
        for t in [f.base_level, f.max_level()] {
            let op = Op::new(&p, t);
            let valid = valid_nodes(&op);
            let (a, split) = (op.assemble(&valid), op.base_matrix(&valid));
            let k = split.kinds();
            if t == f.base_level {
                kinds.iter_mut().zip(k).for_each(|(s, k)| *s += k);
            } else {
                assert_eq!(k[1] + k[2], 0, "{what}, level {t}: rows on a grid");
            }
            let random = masked_random(&valid, 5);
            let zeros: Vec<f64> = random
                .iter()
                .enumerate()
                .map(|(n, &x)| match n % 5 {
                    0 => 0.0,
                    1 => -0.0,
                    _ => x,
                })
                .collect();
            for x in [random, zeros] {
                let (want, got) = (a.apply(&x), split.apply(&x));
                assert_eq!(want.len(), got.len());
                for (n, (w, g)) in want.iter().zip(&got).enumerate() {
                    assert_eq!(
                        w.to_bits(),
                        g.to_bits(),
                        "{what}, level {t}, row {n}: {w} against {g}"
                    );
                }
            }
        }
    }
    // Empty, stencil, own-valued and assembled rows all occurred.
    assert!(kinds.iter().all(|&k| k > 0), "kinds of rows {kinds:?}");
}

/// At degree 1 a V-cycle over the complete depths below the base level preconditions its
/// conjugate gradients, on the assembled matrix and matrix-free alike: 20 iterations reach the
/// tolerance, where the diagonal is still far from it, and the two solutions agree to it. The V-cycle is symmetric and positive, as conjugate
/// gradients need. On base levels of depth 5 (three coarser grids), screened with each
/// boundary, and unscreened (singular); at degree 2 there is none.
#[test]
fn the_base_multigrid_reaches_the_tolerance_in_few_iterations() {
    let cases = [
        (Boundary::Neumann, None),
        (Boundary::Dirichlet, None),
        (Boundary::Free, Some(0.0)),
    ];
    for (boundary, point_weight) in cases {
        let what = format!("{boundary:?}, point weight {point_weight:?}");
        let f =
            Fixture::with_full_depth(sphere(20_000), 7, 5, Degree::Linear, boundary, point_weight);
        let p = f.problem();
        let base = BaseSystem::new(&p);
        let mg = base.multigrid.as_ref().expect("a V-cycle at degree 1");
        assert!(
            mg.coarser_grids() >= 3,
            "{what}: {} coarser grids",
            mg.coarser_grids()
        );
        let a = base.matrix.as_ref().expect("assembled");
        let apply = |x: &[f64]| a.apply(x);
        let mut v = f.v.clone();
        v.resize_with(f.tree.levels.len(), Vec::new);
        let tcons = constraints(&p, &v, p.base_level);
        let b = base.right_hand_side(tcons[f.base_level as usize].clone());
        let residual = |x: &[f64]| norm(&sub(&apply(x), &b)) / norm(&b);
        let pre = |r: &[f64]| mg.precondition(&apply, r);
        let x = conjugate_gradients_with(apply, &base.diag, Some(&pre), &b, &base.valid, 20, 1e-7);
        assert!(residual(&x) <= 1.01e-7, "{what}: {}", residual(&x));
        // The same on the matrix-free operator (base levels too large to assemble).
        let free = |x: &[f64]| base.op.apply(x, &base.valid);
        let pre_free = |r: &[f64]| mg.precondition(&free, r);
        let y =
            conjugate_gradients_with(free, &base.diag, Some(&pre_free), &b, &base.valid, 20, 1e-7);
        assert!(
            residual(&y) <= 1.01e-7,
            "{what}, matrix-free: {}",
            residual(&y)
        );
        let xj = conjugate_gradients(apply, &base.diag, &b, &base.valid, 20, 1e-7);
        assert!(
            residual(&xj) > 1e-5,
            "{what}: the diagonal's {}",
            residual(&xj)
        );
        let mut full = conjugate_gradients(apply, &base.diag, &b, &base.valid, 3000, 1e-7);
        let mut x = x;
        if base.singular() {
            // The solutions are defined up to a constant.
            remove_mean(&mut x, &base.valid);
            remove_mean(&mut full, &base.valid);
        }
        let agree = norm(&sub(&x, &full)) / norm(&full);
        assert!(agree < 1e-5, "{what}: solutions differ by {agree}");
        // Symmetric and positive (on mean-free vectors where the constants are the kernel).
        let mut u = masked_random(&base.valid, 1);
        let mut w = masked_random(&base.valid, 2);
        if base.singular() {
            remove_mean(&mut u, &base.valid);
            remove_mean(&mut w, &base.valid);
        }
        let dot = |a: &[f64], b: &[f64]| a.iter().zip(b).map(|(a, b)| a * b).sum::<f64>();
        let (uw, wu) = (dot(&u, &pre(&w)), dot(&w, &pre(&u)));
        assert!(
            (uw - wu).abs() <= 1e-8 * uw.abs(),
            "{what}: {uw} against {wu}"
        );
        assert!(dot(&u, &pre(&u)) > 0.0, "{what}");
    }
    for (what, f) in fixtures() {
        if f.fem.degree == Degree::Quadratic {
            assert!(BaseSystem::new(&f.problem()).multigrid.is_none(), "{what}");
        }
    }
}

#[test]
fn the_base_solve_meets_its_tolerance() {
    for (what, f) in fixtures() {
        let p = f.problem();
        let mut v = f.v.clone();
        v.resize_with(f.tree.levels.len(), Vec::new);
        let tcons = constraints(&p, &v, p.base_level);
        let tb = f.base_level as usize;
        let x = solve_base(&p, tcons[tb].clone());
        // The right-hand side as `solve_base` builds it.
        let op = Op::new(&p, f.base_level);
        let valid = valid_nodes(&op);
        let mut b: Vec<f64> = tcons[tb].iter().map(|&c| f64::from(c)).collect();
        add_screening_targets(&op, &mut b);
        if f.singular {
            remove_mean(&mut b, &valid);
        }
        let res = norm(&sub(&op.apply(&x, &valid), &b)) / norm(&b);
        assert!(res <= 1.01e-7, "{what}: relative residual {res}");
        assert!(x.iter().zip(&valid).all(|(&x, &v)| v || x == 0.0));
    }
}

/// The right-hand side of the finest level for a zero coarser solution and V: its own
/// constraints and the screening targets.
fn finest_right_hand_side(f: &Fixture, op: &Op) -> Vec<f32> {
    let p = f.problem();
    let mut v = f.v.clone();
    v.resize_with(f.tree.levels.len(), Vec::new);
    let tcons = constraints(&p, &v, p.base_level);
    let parent_len = f.tree.levels[op.t as usize - 1].len();
    right_hand_side(
        op,
        f.fem,
        tcons[op.t as usize].clone(),
        &vec![0.0; parent_len],
        &vec![[0.0; 3]; parent_len],
        &[],
    )
}

#[test]
fn gauss_seidel_gives_the_same_bits_on_one_and_four_threads() {
    for (what, f) in fixtures() {
        let p = f.problem();
        let op = Op::new(&p, f.max_level());
        let blocks = op.colour_blocks();
        assert!(
            blocks.iter().any(|list| list.len() > 1),
            "{what}: the sweep should run blocks in parallel"
        );
        // The blocks cover every brood once.
        let mut all: Vec<(u32, u32)> = blocks.concat();
        all.sort_unstable();
        assert_eq!(all[0].0, 0, "{what}");
        assert!(all.windows(2).all(|w| w[0].1 == w[1].0), "{what}");
        assert_eq!(all.last().unwrap().1 as usize, op.level.len() / 8, "{what}");
        let r = finest_right_hand_side(f, &op);
        let sweep = |threads| {
            with_threads(threads, || {
                let mut x = vec![0.0f32; op.level.len()];
                op.gauss_seidel(&r, &mut x, 3);
                x.iter().map(|x| x.to_bits()).collect::<Vec<u32>>()
            })
        };
        let one = sweep(1);
        assert!(one.iter().any(|&b| b != 0), "{what}: nothing solved");
        assert_eq!(one, sweep(4), "{what}");
    }
}

#[test]
fn gauss_seidel_gives_the_same_bits_in_every_compiled_copy() {
    // The AVX2 copy runs the brood sums four lanes at a time instead of two; the bits must
    // not change (no fused multiply-adds, the same order). Where the processor has no AVX2
    // both runs take the baseline copy.
    let wide = Wide::detect();
    for (what, f) in fixtures() {
        let p = f.problem();
        let op = Op::new(&p, f.max_level());
        let r = finest_right_hand_side(f, &op);
        let sweep = |copy| {
            let mut x = vec![0.0f32; op.level.len()];
            op.gauss_seidel_with(&r, &mut x, 3, copy);
            x.iter().map(|x| x.to_bits()).collect::<Vec<u32>>()
        };
        let baseline = sweep(Wide::Baseline);
        assert!(baseline.iter().any(|&b| b != 0), "{what}: nothing solved");
        assert_eq!(baseline, sweep(wide), "{what}: {wide:?}");
    }
}

#[test]
fn the_cascade_gives_the_same_bits_on_one_and_four_threads() {
    let f = &fixtures()[1].1;
    let run = |threads| {
        with_threads(threads, || {
            let s = solve(&f.problem(), f.v.clone());
            let bits = |v: &[Vec<f32>]| -> Vec<Vec<u32>> {
                v.iter()
                    .map(|l| l.iter().map(|x| x.to_bits()).collect())
                    .collect()
            };
            (bits(&s.x), bits(&s.p))
        })
    };
    assert_eq!(run(1), run(4));
}

#[test]
fn gauss_seidel_lowers_the_energy_with_every_sweep() {
    for (what, f) in fixtures() {
        let p = f.problem();
        let op = Op::new(&p, f.max_level());
        let valid = valid_nodes(&op);
        let r = finest_right_hand_side(f, &op);
        let r64: Vec<f64> = r.iter().map(|&v| f64::from(v)).collect();
        // E(x) = ½ xᵀAx − rᵀx, which each relaxation minimises along its coordinate.
        let energy = |x: &[f64]| {
            let ax = op.apply(x, &valid);
            (0..x.len())
                .map(|n| x[n] * (0.5 * ax[n] - r64[n]))
                .sum::<f64>()
        };
        let residual = |x: &[f64]| norm(&sub(&r64, &op.apply(x, &valid)));
        let mut x = vec![0.0f32; op.level.len()];
        let to64 = |x: &[f32]| x.iter().map(|&v| f64::from(v)).collect::<Vec<f64>>();
        let mut e = energy(&to64(&x));
        let r0 = residual(&to64(&x));
        for sweep in 1..=6 {
            op.gauss_seidel(&r, &mut x, 1);
            let e_new = energy(&to64(&x));
            assert!(
                e_new < e,
                "{what}: sweep {sweep} raised the energy {e} to {e_new}"
            );
            e = e_new;
        }
        let r6 = residual(&to64(&x));
        assert!(r6 < 0.5 * r0, "{what}: residual {r0} to {r6} in six sweeps");
    }
}

/// The solution's bits, level by level (`x`, then `p`).
fn solution_bits(s: &Solution) -> (Vec<Vec<u32>>, Vec<Vec<u32>>) {
    let bits = |v: &[Vec<f32>]| -> Vec<Vec<u32>> {
        v.iter()
            .map(|l| l.iter().map(|x| x.to_bits()).collect())
            .collect()
    };
    (bits(&s.x), bits(&s.p))
}

#[test]
fn one_cascadic_cycle_with_residuals_is_the_cascade_bit_for_bit() {
    for (what, f) in fixtures() {
        let plain = solve(&f.problem(), f.v.clone());
        let reported = solve(
            &Problem {
                report: true,
                ..f.problem()
            },
            f.v.clone(),
        );
        assert!(plain.report.is_none());
        let report = reported.report.as_ref().expect("asked for");
        assert_eq!(report.after_cycle.len(), 1, "{what}");
        assert_eq!(solution_bits(&plain), solution_bits(&reported), "{what}");
    }
}

#[test]
fn every_cycle_lowers_the_residual_and_so_does_every_relaxation_on_its_depth() {
    for (what, f) in fixtures() {
        for solver in [Solver::VCycle, Solver::WCycle, Solver::Cascadic] {
            let s = solve(
                &Problem {
                    solver,
                    cycles: 3,
                    report: true,
                    ..f.problem()
                },
                f.v.clone(),
            );
            let r = s.report.expect("asked for");
            assert_eq!(r.after_cycle.len(), 3, "{what} {solver:?}");
            for d in &r.depths {
                assert!(d.after < d.before, "{what} {solver:?}: {d:?}");
            }
            for k in 1..r.after_cycle.len() {
                assert!(
                    r.after_cycle[k] < r.after_cycle[k - 1],
                    "{what} {solver:?}: cycle {} raised the residual: {:?}",
                    k + 1,
                    r.after_cycle
                );
            }
        }
    }
}

#[test]
fn the_cycles_give_the_same_bits_on_one_and_four_threads() {
    let f = &fixtures()[0].1;
    for solver in [Solver::VCycle, Solver::WCycle, Solver::Cascadic] {
        let run = |threads| {
            with_threads(threads, || {
                let p = Problem {
                    solver,
                    cycles: 2,
                    ..f.problem()
                };
                solution_bits(&solve(&p, f.v.clone()))
            })
        };
        assert_eq!(run(1), run(4), "{solver:?}");
    }
}

#[test]
fn the_deepest_levels_parent_kept_near_it_alone_gives_the_same_bits() {
    for degree in [Degree::Linear, Degree::Quadratic] {
        let f = Fixture::with_deep_patch(degree, Boundary::Neumann);
        let p = f.problem();
        let max = f.max_level();
        let top = Op::new(&p, max - 1);
        let near = top.level.broods_near_children();
        assert!(
            deepest_reads_little(&top) && near > 0,
            "{degree:?}: {near} of {} broods near the deepest level",
            top.level.len() / 8
        );
        // Where it is kept, it is the whole prolongation's; elsewhere zero.
        let pc = pseudo_random(f.tree.levels[max as usize - 2].len(), 3);
        let x = to_f32(&pseudo_random(top.level.len(), 4));
        let whole = prolong_solution(&top, &pc, &x);
        let kept = prolong_solution_for_deepest(&top, &pc, &x);
        for (n, (w, k)) in whole.iter().zip(&kept).enumerate() {
            let expected = if top.level.row_has_children(n as u32 / 8) {
                *w
            } else {
                0.0
            };
            assert_eq!(k.to_bits(), expected.to_bits(), "{degree:?}: node {n}");
        }
        assert_eq!(
            prolong_solution_f32(&top, &pc, &x),
            to_f32(&whole),
            "{degree:?}"
        );
        // The solve, with every solver, is the same with the parent level kept whole.
        for (solver, cycles) in [
            (Solver::Cascadic, 1),
            (Solver::Cascadic, 2),
            (Solver::VCycle, 2),
            (Solver::WCycle, 2),
        ] {
            let p = Problem {
                solver,
                cycles,
                ..f.problem()
            };
            let near = solution_bits(&solve(&p, f.v.clone()));
            KEEP_WHOLE.store(true, std::sync::atomic::Ordering::Relaxed);
            let whole = solution_bits(&solve(&p, f.v.clone()));
            KEEP_WHOLE.store(false, std::sync::atomic::Ordering::Relaxed);
            assert_eq!(near, whole, "{degree:?} {solver:?} {cycles}");
        }
    }
}

#[test]
fn the_hierarchical_stiffness_is_symmetric() {
    for (what, f) in fixtures() {
        let p = f.problem();
        let tb = f.base_level as usize;
        let rand = |seed: u64| -> Vec<Vec<f32>> {
            (0..f.tree.levels.len())
                .map(|t| {
                    if t < tb {
                        return Vec::new();
                    }
                    let op = Op::new(&p, t as u32);
                    masked_random(&valid_nodes(&op), seed + t as u64)
                        .iter()
                        .map(|&v| v as f32)
                        .collect()
                })
                .collect()
        };
        let (x, y) = (rand(1), rand(100));
        let (mx, my) = (
            cycles::apply_stiffness(&p, &x),
            cycles::apply_stiffness(&p, &y),
        );
        let dot = |a: &[Vec<f32>], b: &[Vec<f64>]| -> Vec<f64> {
            a.iter()
                .zip(b)
                .map(|(a, b)| a.iter().zip(b).map(|(&u, v)| f64::from(u) * v).sum())
                .collect()
        };
        let (ymx, xmy) = (dot(&y, &mx), dot(&x, &my));
        let (s1, s2): (f64, f64) = (ymx.iter().sum(), xmy.iter().sum());
        assert!(
            (s1 - s2).abs() < 1e-9 * s1.abs().max(1.0),
            "{what}: {s1} vs {s2}"
        );
    }
}

/// Random inputs of level `t`'s right-hand sides: its constraints, and the parent level's
/// cumulative solution and V, every third parent's V zero (the boundary coupling skips those).
#[cfg(feature = "gpu")]
pub(super) fn right_hand_side_inputs(f: &Fixture, t: u32) -> (Vec<f32>, Vec<f64>, Vec<[f32; 3]>) {
    let seed = u64::from(t);
    let (nodes, parents) = (
        f.tree.levels[t as usize].len(),
        f.tree.levels[t as usize - 1].len(),
    );
    let tcons = pseudo_random(nodes, 11 + seed)
        .iter()
        .map(|&x| x as f32)
        .collect();
    let pc = pseudo_random(parents, 13 + seed);
    let vc = pseudo_random(3 * parents, 17 + seed)
        .chunks(3)
        .enumerate()
        .map(|(q, v)| match q % 3 {
            0 => [0.0; 3],
            _ => [v[0] as f32, v[1] as f32, v[2] as f32],
        })
        .collect();
    (tcons, pc, vc)
}

/// On a GPU, every level's right-hand sides, sweeps, prolongations and finer coupling give
/// the CPU's values bit for bit (from random inputs, with some coarser V zero, and from zero and a nonzero
/// start), and so does the whole solve, with every solver path: the cascade alone, cascadic cycles and V-cycles.
/// Skipped, with a message, where no GPU can be used.
#[cfg(feature = "gpu")]
#[test]
fn the_gpu_gives_the_cpus_bits() {
    use crate::gpu::GpuKernel;
    let bits = |v: &[f32]| v.iter().map(|x| x.to_bits()).collect::<Vec<u32>>();
    let as_f32 = |v: Vec<f64>| v.iter().map(|&x| x as f32).collect::<Vec<f32>>();
    for (what, f) in fixtures() {
        let dev = match Device::open(f.fem.degree.get()) {
            Ok(dev) => dev,
            Err(reason) => {
                eprintln!("skipped: no usable GPU ({reason})");
                return;
            }
        };
        let cpu_p = f.problem();
        let gpu_p = Problem {
            gpu: Some(&dev),
            ..f.problem()
        };
        for t in f.base_level + 1..=f.max_level() {
            let (cpu_op, gpu_op) = (Op::new(&cpu_p, t), Op::new(&gpu_p, t));
            let seed = u64::from(t);
            let (tcons, pc, vc) = right_hand_side_inputs(f, t);
            let (r_cpu, b_cpu) =
                super::cycles::right_hand_sides(&cpu_op, f.fem, tcons.clone(), &pc, &vc);
            let (r_gpu, b_gpu) =
                super::cycles::right_hand_sides(&gpu_op, f.fem, tcons.clone(), &pc, &vc);
            assert_eq!(bits(&r_cpu), bits(&r_gpu), "{what}, level {t}: r");
            assert_eq!(bits(&b_cpu), bits(&b_gpu), "{what}, level {t}: b");
            let single = super::right_hand_side(&gpu_op, f.fem, tcons.clone(), &pc, &vc, &[]);
            assert_eq!(
                bits(&r_cpu),
                bits(&single),
                "{what}, level {t}: cascade's r"
            );
            let r = as_f32(pseudo_random(cpu_op.level.len(), seed));
            let start = as_f32(pseudo_random(cpu_op.level.len(), 7 + seed));
            for x0 in [vec![0.0f32; cpu_op.level.len()], start] {
                let mut cpu = x0.clone();
                cpu_op.gauss_seidel_cpu(&r, &mut cpu, 3);
                let mut gpu = x0;
                assert!(
                    gpu_op.gauss_seidel_gpu(&r, &mut gpu, 3),
                    "{what}, level {t}"
                );
                assert_eq!(bits(&cpu), bits(&gpu), "{what}, level {t}: sweeps");
            }
            let f64_bits = |v: &[f64]| v.iter().map(|x| x.to_bits()).collect::<Vec<u64>>();
            let x = as_f32(pseudo_random(cpu_op.level.len(), 23 + seed));
            dev.take_timings();
            assert_eq!(
                f64_bits(&super::prolong_solution(&cpu_op, &pc, &x)),
                f64_bits(&super::prolong_solution(&gpu_op, &pc, &x)),
                "{what}, level {t}: the cumulative solution"
            );
            let vt = vec![[0.5f32, -0.25, 0.125]; cpu_op.level.len()];
            let cpu = super::prolong_field(&cpu_op, &vc, vt.clone());
            let gpu = super::prolong_field(&gpu_op, &vc, vt);
            assert_eq!(
                bits(cpu.as_flattened()),
                bits(gpu.as_flattened()),
                "{what}, level {t}: the cumulative V"
            );
            let prolonged = dev.take_timings();
            assert_eq!(
                (prolonged.iter())
                    .filter(|s| s.kind == GpuKernel::Prolongation)
                    .count(),
                2,
                "{what}, level {t}: the prolongations did not run on the GPU"
            );
            let u = pseudo_random(cpu_op.level.len(), 29 + seed);
            for u in [Vec::new(), u] {
                let cpu = super::cycles::coupling_below_of(&cpu_p, &cpu_op, &x, &u);
                dev.take_timings();
                let gpu = super::cycles::coupling_below_of(&gpu_p, &gpu_op, &x, &u);
                assert!(
                    dev.take_timings()
                        .iter()
                        .any(|s| s.kind == GpuKernel::Coupling),
                    "{what}, level {t}: the coupling did not run on the GPU"
                );
                assert_eq!(
                    f64_bits(&cpu),
                    f64_bits(&gpu),
                    "{what}, level {t}: coupling"
                );
            }
            assert_eq!(dev.take_failure(), None, "{what}, level {t}");
        }
        let mut v = f.v.clone();
        v.resize_with(f.tree.levels.len(), Vec::new);
        let cpu_t = constraints(&cpu_p, &v, f.base_level);
        let gpu_t = constraints(&gpu_p, &v, f.base_level);
        assert_eq!(dev.take_failure(), None, "{what}: constraints");
        for (t, (c, g)) in cpu_t.iter().zip(&gpu_t).enumerate() {
            assert_eq!(bits(c), bits(g), "{what}, level {t}: constraints");
        }
        for (solver, cycles) in [
            (crate::Solver::Cascadic, 1),
            (crate::Solver::Cascadic, 2),
            (crate::Solver::VCycle, 2),
        ] {
            let cpu = solve(
                &Problem {
                    solver,
                    cycles,
                    ..f.problem()
                },
                f.v.clone(),
            );
            dev.take_timings();
            let gpu = solve(
                &Problem {
                    solver,
                    cycles,
                    gpu: Some(&dev),
                    ..f.problem()
                },
                f.v.clone(),
            );
            assert_eq!(dev.take_failure(), None, "{what}");
            let steps = dev.take_timings();
            let coupled = (cycles > 1).then_some(GpuKernel::Coupling);
            for kind in [
                GpuKernel::Constraints,
                GpuKernel::RightHandSide,
                GpuKernel::Relaxation,
                GpuKernel::Prolongation,
            ]
            .into_iter()
            .chain(coupled)
            {
                assert!(
                    steps.iter().any(|s| s.kind == kind),
                    "{what} {solver:?} x {cycles}: no {kind:?} on the GPU"
                );
            }
            assert_eq!(
                solution_bits(&cpu),
                solution_bits(&gpu),
                "{what} {solver:?} x {cycles}"
            );
        }
        eprintln!("{what}: the GPU ({}) gave the CPU's bits", dev.name());
    }
}

/// Each screening cluster's stored window (its first index modulo 256 and `degree + 1` values
/// per axis) gives back the B-spline window at its position: the first index from the
/// cluster's own node and from every function it touches, and the basis values of the
/// functions in and just outside the window.
#[test]
fn clusters_give_back_their_windows() {
    let mut checked = 0;
    for (name, fx) in fixtures() {
        let degree = fx.fem.degree.get();
        for t in fx.base_level..=fx.max_level() {
            let d = t - DEPTH_OFFSET;
            let level = &fx.tree.levels[t as usize];
            let cl = &fx.clusters[t as usize];
            checked += cl.len();
            for c in 0..cl.len() {
                // The position is kept in single precision, the window was made from the
                // double one: skip the few clusters within rounding of a cell's face.
                let p = cl.pos[c].map(f64::from);
                let h = f64::from(1u32 << d);
                if p.iter().any(|&x| ((x * h).round() - x * h).abs() < 1e-4) {
                    continue;
                }
                let own = func_index(level.key(cl.node[c]), d);
                let win: [_; 3] = std::array::from_fn(|a| fx.fem.window(d, p[a]));
                let first = win.map(|w| w.first);
                assert_eq!(cl.first(c, own), first, "{name}: level {t} cluster {c}");
                for (a, w) in win.iter().enumerate() {
                    for k in 0..=usize::from(degree) {
                        let v = cl.axis_value(c, a, k);
                        assert!((v - w.values[k] as f32).abs() <= 1e-5, "{name}: {v} {k}");
                    }
                }
                // Every function of the window and of a ring one wider around it.
                let r = i64::from(degree) + 1;
                for dz in -1..=r {
                    for dy in -1..=r {
                        for dx in -1..=r {
                            let k = [dx, dy, dz];
                            let i: [i64; 3] = std::array::from_fn(|a| first[a] + k[a]);
                            assert_eq!(cl.first(c, i), first);
                            let inside = k.iter().all(|&v| (0..r).contains(&v));
                            let want: f64 = if inside {
                                (0..3)
                                    .map(|a| f64::from(cl.axis_value(c, a, k[a] as usize)))
                                    .product()
                            } else {
                                0.0
                            };
                            assert_eq!(cl.basis_value(c, i, degree), want, "{name}: {k:?}");
                        }
                    }
                }
            }
        }
    }
    assert!(checked > 10_000, "{checked} clusters checked");
}

#[test]
fn the_parent_push_taken_one_axis_at_a_time_is_each_childs_parent_window() {
    let mut state = 0x5851_f42d_4c95_7f2du64;
    let mut noise = || {
        state ^= state << 13;
        state ^= state >> 7;
        state ^= state << 17;
        (state >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    };
    for degree in [Degree::Linear, Degree::Quadratic] {
        for boundary in [Boundary::Neumann, Boundary::Dirichlet, Boundary::Free] {
            let fem = crate::bspline::Basis::new(degree, boundary);
            let vb = crate::bspline::Basis::new(Degree::Quadratic, boundary.derivative());
            let tab = crate::system::DepthTables::new(fem, vb, 4);
            let (lo, hi) = (tab.range.lo, tab.range.hi);
            let even = |i: i64| i - i.rem_euclid(2);
            // Broods against each end (some children outside the range) and in the middle.
            for i0 in [
                [even(lo), even(hi), even(lo) + 2],
                [even((lo + hi) / 2); 3],
                [even(hi), even(lo), even(hi) - 2],
            ] {
                let x: [f64; 8] = std::array::from_fn(|_| noise());
                let got = cycles::parent_stiffness_push(&tab, i0, x);
                let (mut want, mut scale) = ([0.0f64; 125], [0.0f64; 125]);
                for (c, &xc) in x.iter().enumerate() {
                    let i: [i64; 3] = std::array::from_fn(|a| i0[a] + ((c >> a) & 1) as i64);
                    if !tab.range.contains(i) {
                        continue;
                    }
                    for w in 0..125 {
                        let o = [w % 5 - 2, w / 5 % 5 - 2, w / 25 - 2];
                        let m: [f64; 3] = std::array::from_fn(|a| tab.pmass.get(i[a], o[a]));
                        let k: [f64; 3] = std::array::from_fn(|a| tab.pstiff.get(i[a], o[a]));
                        let terms = [k[0] * m[1] * m[2], m[0] * k[1] * m[2], m[0] * m[1] * k[2]];
                        want[w as usize] += xc * terms.iter().sum::<f64>();
                        scale[w as usize] += terms.iter().map(|t| (xc * t).abs()).sum::<f64>();
                    }
                }
                for w in 0..125 {
                    assert!(
                        (got[w] - want[w]).abs() <= 1e-13 * scale[w],
                        "{degree:?} {boundary:?} brood {i0:?} window {w}: {} vs {}",
                        got[w],
                        want[w]
                    );
                }
                // The middle brood reaches at least a 3×3×3 window.
                if i0[0] == i0[1] {
                    assert!(scale.iter().filter(|&&s| s > 0.0).count() >= 27);
                }
            }
        }
    }
}
