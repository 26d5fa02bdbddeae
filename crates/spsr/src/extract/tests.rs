//! Extraction tests on analytic fields and synthetic octrees.

use super::blocks::extract_impl;
use super::vertex::edge_root;
use super::*;
use crate::mesh::{Mesh, Topology};
use crate::vec3::{norm, norm2, sub};
use std::collections::{HashMap, HashSet};

// ---------------------------------------------------------------- fields

/// An analytic field given in unit-cube coordinates, with a distance-like function used to
/// decide where to refine.
trait Analytic: Sync {
    fn eval(&self, p: [f64; 3]) -> (f64, [f64; 3]);
    fn dist(&self, p: [f64; 3]) -> f64;
}

struct Grid<'a, A: Analytic + ?Sized> {
    f: &'a A,
    inv: f64,
}

impl<A: Analytic + ?Sized> Field for Grid<'_, A> {
    fn corner(&self, c: [u32; 3], _near: ()) -> (f64, [f64; 3]) {
        self.f.eval(c.map(|x| x as f64 * self.inv))
    }
}

/// χ = 1 − |p − c|²/r² (a quadric: the quadratic fit is exact on grid edges).
struct Sphere {
    c: [f64; 3],
    r: f64,
}

impl Analytic for Sphere {
    fn eval(&self, p: [f64; 3]) -> (f64, [f64; 3]) {
        let d = sub(p, self.c);
        let r2 = self.r * self.r;
        (1.0 - norm2(d) / r2, d.map(|x| -2.0 * x / r2))
    }
    fn dist(&self, p: [f64; 3]) -> f64 {
        (norm(sub(p, self.c)) - self.r).abs()
    }
}

/// χ = r² − |p − c|², evaluated exactly for dyadic c and r so corners can hit iso = 0.
struct ExactSphere {
    c: [f64; 3],
    r: f64,
}

impl Analytic for ExactSphere {
    fn eval(&self, p: [f64; 3]) -> (f64, [f64; 3]) {
        let d = sub(p, self.c);
        (self.r * self.r - norm2(d), d.map(|x| -2.0 * x))
    }
    fn dist(&self, p: [f64; 3]) -> f64 {
        (norm(sub(p, self.c)) - self.r).abs()
    }
}

/// Axis-aligned box: χ = h − max|p_i − 0.5| (whole grid planes of corners sit on iso 0).
struct BoxField {
    h: f64,
}

impl Analytic for BoxField {
    fn eval(&self, p: [f64; 3]) -> (f64, [f64; 3]) {
        let d = p.map(|x| x - 0.5);
        let mut a = 0;
        for i in 1..3 {
            if d[i].abs() > d[a].abs() {
                a = i;
            }
        }
        let mut g = [0.0; 3];
        g[a] = -d[a].signum();
        (self.h - d[a].abs(), g)
    }
    fn dist(&self, p: [f64; 3]) -> f64 {
        let m = p.iter().map(|x| (x - 0.5).abs()).fold(0.0, f64::max);
        (m - self.h).abs()
    }
}

/// Torus around the z axis through c: χ = r² − ((q − R)² + z²), q = distance to the axis.
struct Torus {
    c: [f64; 3],
    big: f64,
    small: f64,
}

impl Analytic for Torus {
    fn eval(&self, p: [f64; 3]) -> (f64, [f64; 3]) {
        let d = sub(p, self.c);
        let q = (d[0] * d[0] + d[1] * d[1]).sqrt().max(1e-300);
        let k = q - self.big;
        (
            self.small * self.small - (k * k + d[2] * d[2]),
            [-2.0 * k * d[0] / q, -2.0 * k * d[1] / q, -2.0 * d[2]],
        )
    }
    fn dist(&self, p: [f64; 3]) -> f64 {
        let d = sub(p, self.c);
        let q = (d[0] * d[0] + d[1] * d[1]).sqrt();
        (((q - self.big).powi(2) + d[2] * d[2]).sqrt() - self.small).abs()
    }
}

/// Union of two spheres: χ = max(χ1, χ2).
struct TwoSpheres(Sphere, Sphere);

impl Analytic for TwoSpheres {
    fn eval(&self, p: [f64; 3]) -> (f64, [f64; 3]) {
        let (a, b) = (self.0.eval(p), self.1.eval(p));
        if a.0 >= b.0 {
            a
        } else {
            b
        }
    }
    fn dist(&self, p: [f64; 3]) -> f64 {
        self.0.dist(p).min(self.1.dist(p))
    }
}

// ---------------------------------------------------------------- trees

fn splitmix64(mut x: u64) -> u64 {
    x = x.wrapping_add(0x9e37_79b9_7f4a_7c15);
    x = (x ^ (x >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    x = (x ^ (x >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    x ^ (x >> 31)
}

/// A uniform random number in [0, 1) attached to a cell.
fn cell_rand(seed: u64, depth: u32, o: [u32; 3]) -> f64 {
    let k = splitmix64(seed ^ splitmix64(depth as u64 ^ pack(o).wrapping_mul(31)));
    (k >> 11) as f64 / (1u64 << 53) as f64
}

fn center(depth: u32, o: [u32; 3]) -> ([f64; 3], f64) {
    let w = 1.0 / (1u64 << depth) as f64;
    (o.map(|x| (x as f64 + 0.5) * w), w)
}

/// Leaves of the tree whose internal nodes are `internal` (root first, children in order).
fn leaves_of(internal: &HashSet<(u32, [u32; 3])>) -> Vec<Leaf> {
    let mut out = Vec::new();
    let mut stack = vec![(0u32, [0u32; 3])];
    while let Some((d, o)) = stack.pop() {
        if internal.contains(&(d, o)) {
            for c in (0..8u32).rev() {
                stack.push((
                    d + 1,
                    [
                        2 * o[0] + (c & 1),
                        2 * o[1] + ((c >> 1) & 1),
                        2 * o[2] + (c >> 2),
                    ],
                ));
            }
        } else {
            out.push(Leaf {
                depth: d,
                offset: o,
            });
        }
    }
    out
}

/// Internal nodes from a split predicate (applied top-down).
fn internal_from(
    max_depth: u32,
    split: &dyn Fn(u32, [u32; 3]) -> bool,
) -> HashSet<(u32, [u32; 3])> {
    let mut internal = HashSet::new();
    let mut stack = vec![(0u32, [0u32; 3])];
    while let Some((d, o)) = stack.pop() {
        if d < max_depth && split(d, o) {
            internal.insert((d, o));
            for c in 0..8u32 {
                stack.push((
                    d + 1,
                    [
                        2 * o[0] + (c & 1),
                        2 * o[1] + ((c >> 1) & 1),
                        2 * o[2] + (c >> 2),
                    ],
                ));
            }
        }
    }
    internal
}

/// Adds internal nodes until touching leaves differ by at most one depth.
fn grade(internal: &mut HashSet<(u32, [u32; 3])>) {
    let mut work: Vec<(u32, [u32; 3])> = internal.iter().copied().collect();
    work.sort_unstable();
    while let Some((k, o)) = work.pop() {
        if k < 1 {
            continue;
        }
        // All neighbours of the parent (depth k−1) must be internal.
        let (gd, go) = (k - 1, o.map(|x| x / 2));
        let n = 1i64 << gd;
        for dz in -1i64..=1 {
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let q = [go[0] as i64 + dx, go[1] as i64 + dy, go[2] as i64 + dz];
                    if q.iter().any(|&x| x < 0 || x >= n) {
                        continue;
                    }
                    // Insert the neighbour and its ancestors.
                    let (mut d, mut c) = (gd, q.map(|x| x as u32));
                    loop {
                        if internal.insert((d, c)) {
                            work.push((d, c));
                        } else {
                            break;
                        }
                        if d == 0 {
                            break;
                        }
                        d -= 1;
                        c = c.map(|x| x / 2);
                    }
                }
            }
        }
    }
}

fn uniform(depth: u32) -> Vec<Leaf> {
    leaves_of(&internal_from(depth, &|_, _| true))
}

/// (b) Refined to `max` within about two cell widths of the surface, at least `min`, then
/// 2:1 graded.
fn adaptive_graded(f: &dyn Analytic, min: u32, max: u32) -> Vec<Leaf> {
    let mut internal = internal_from(max, &|d, o| {
        let (p, w) = center(d, o);
        d < min || f.dist(p) < (0.87 + 2.0) * w
    });
    grade(&mut internal);
    leaves_of(&internal)
}

/// (c) Only cells the surface may cross are refined: neighbours differ by up to max − min.
fn non_graded(f: &dyn Analytic, min: u32, max: u32) -> Vec<Leaf> {
    leaves_of(&internal_from(max, &|d, o| {
        let (p, w) = center(d, o);
        d < min || f.dist(p) < 0.87 * w
    }))
}

/// (d) Random refinement, denser near the surface.
fn random_tree(f: &dyn Analytic, seed: u64, max: u32) -> Vec<Leaf> {
    leaves_of(&internal_from(max, &|d, o| {
        let (p, w) = center(d, o);
        let r = cell_rand(seed, d, o);
        d < 1 || (f.dist(p) < 3.0 * w && (d < max - 2 || r < 0.6)) || r < 0.12
    }))
}

/// Largest depth difference between leaves that touch (checked through face, edge and
/// corner neighbours of the finest cells along each leaf's boundary; small trees only).
fn max_jump(leaves: &[Leaf], max_depth: u32) -> u32 {
    let mut owner: HashMap<[u32; 3], u32> = HashMap::new();
    for l in leaves {
        let s = 1u32 << (max_depth - l.depth);
        let lo = l.offset.map(|o| o * s);
        for z in 0..s {
            for y in 0..s {
                for x in 0..s {
                    if x == 0 || y == 0 || z == 0 || x == s - 1 || y == s - 1 || z == s - 1 {
                        owner.insert([lo[0] + x, lo[1] + y, lo[2] + z], l.depth);
                    }
                }
            }
        }
    }
    let n = 1i64 << max_depth;
    let mut jump = 0;
    for (c, &d) in &owner {
        for dz in -1i64..=1 {
            for dy in -1i64..=1 {
                for dx in -1i64..=1 {
                    let q = [c[0] as i64 + dx, c[1] as i64 + dy, c[2] as i64 + dz];
                    if q.iter().any(|&x| x < 0 || x >= n) {
                        continue;
                    }
                    if let Some(&e) = owner.get(&q.map(|x| x as u32)) {
                        jump = jump.max(d.abs_diff(e));
                    }
                }
            }
        }
    }
    jump
}

// ---------------------------------------------------------------- checks

/// Number of sign-changing finest edges, by brute force.
fn brute_force_crossings(leaves: &[Leaf], max_depth: u32, f: &dyn Field, iso: f64) -> usize {
    let mut corners = HashSet::new();
    for l in leaves {
        let s = 1u32 << (max_depth - l.depth);
        for c in 0..8u32 {
            corners.insert([
                l.offset[0] * s + s * (c & 1),
                l.offset[1] * s + s * ((c >> 1) & 1),
                l.offset[2] * s + s * (c >> 2),
            ]);
        }
    }
    let mut edges = HashSet::new();
    for l in leaves {
        let s = 1u32 << (max_depth - l.depth);
        let lo = l.offset.map(|o| o * s);
        for a in 0..3 {
            for e in 0..4u32 {
                let (b, c) = ((a + 1) % 3, (a + 2) % 3);
                let mut p = lo;
                p[b] += s * (e & 1);
                p[c] += s * (e >> 1);
                let mut start = p;
                for t in 1..=s {
                    let mut q = p;
                    q[a] += t;
                    if corners.contains(&q) {
                        edges.insert((start, q));
                        start = q;
                    }
                }
            }
        }
    }
    edges
        .iter()
        .filter(|(a, b)| (f.corner(*a, ()).0 > iso) != (f.corner(*b, ()).0 > iso))
        .count()
}

fn run(
    leaves: &[Leaf],
    max_depth: u32,
    f: &dyn Analytic,
    iso: f64,
    linear: bool,
) -> (Mesh, usize, Vec<bool>) {
    let grid = Grid {
        f,
        inv: 1.0 / (1u64 << max_depth) as f64,
    };
    let opts = ExtractOptions {
        linear_fit: linear,
        ..Default::default()
    };
    extract_impl(leaves, max_depth, &grid, iso, &opts).unwrap()
}

/// Checks shared by all closed-surface cases; returns the topology.
fn check_closed(
    name: &str,
    leaves: &[Leaf],
    max_depth: u32,
    f: &dyn Analytic,
    iso: f64,
    components: usize,
    euler: i64,
) -> (Mesh, Vec<bool>, Topology) {
    let grid = Grid {
        f,
        inv: 1.0 / (1u64 << max_depth) as f64,
    };
    let (mesh, n_edge, is_edge) = run(leaves, max_depth, f, iso, false);
    let t = mesh.topology();
    assert!(t.closed, "{name}: not closed: {t:?}");
    assert!(
        t.edge_manifold && t.vertex_manifold,
        "{name}: not manifold: {t:?}"
    );
    assert!(t.oriented, "{name}: not oriented: {t:?}");
    assert_eq!(t.components, components, "{name}: {t:?}");
    assert_eq!(t.euler, euler, "{name}: {t:?}");
    assert!(mesh.signed_volume() > 0.0, "{name}: negative volume");
    assert_eq!(
        n_edge,
        brute_force_crossings(leaves, max_depth, &grid, iso),
        "{name}: one vertex per crossing finest edge"
    );
    // Linear fit gives the same topology.
    let (lin, _, _) = run(leaves, max_depth, f, iso, true);
    let tl = lin.topology();
    assert!(
        tl.closed && tl.vertex_manifold && tl.oriented && tl.euler == euler,
        "{name} linear: {tl:?}"
    );
    (mesh, is_edge, t)
}

/// Every edge vertex (two coordinates on the grid) has |χ − iso| tiny where the quadratic fit
/// is exact; returns the number checked.
fn check_on_surface(mesh: &Mesh, is_edge: &[bool], max_depth: u32, s: &Sphere) -> usize {
    let scale = (1u64 << max_depth) as f64;
    let w = 1.0 / scale;
    let mut n = 0;
    assert_eq!(is_edge.len(), mesh.vertices.len());
    for (v, &e) in mesh.vertices.iter().zip(is_edge) {
        let on_grid = v.iter().filter(|x| (*x * scale).fract() == 0.0).count() >= 2;
        assert!(!e || on_grid, "edge vertex {v:?} not on a grid line");
        if e {
            n += 1;
            let e = s.dist(*v);
            assert!(e <= 1e-3 * w, "vertex {v:?} off the surface by {e}");
        }
    }
    n
}

fn sphere() -> Sphere {
    Sphere {
        c: [0.51, 0.48, 0.503],
        r: 0.3,
    }
}

fn sphere_volume(r: f64) -> f64 {
    4.0 / 3.0 * std::f64::consts::PI * r * r * r
}

// ---------------------------------------------------------------- tests

#[test]
fn quadratic_fit_is_exact_for_quadratics() {
    // f(t) = (t − 0.3)(t + 0.5) − has its root at 0.3 in [0, 1].
    let f = |t: f64| (t - 0.3) * (t + 0.5);
    let g = |t: f64| 2.0 * t + 0.2;
    let t = edge_root(f(0.0), f(1.0), g(0.0), g(1.0), false);
    assert!((t - 0.3).abs() < 1e-14, "{t}");
    // Linear fit.
    let t = edge_root(-1.0, 3.0, 0.0, 0.0, true);
    assert!((t - 0.25).abs() < 1e-15);
    // Degenerate derivatives fall back to linear interpolation.
    let t = edge_root(-1.0, 3.0, 1.0, -1.0, false);
    assert!((t - 0.25).abs() < 1e-15);
}

#[test]
fn sphere_uniform_depth5() {
    let s = sphere();
    let leaves = uniform(5);
    let (mesh, is_edge, _) = check_closed("uniform", &leaves, 5, &s, 0.0, 1, 2);
    assert!(check_on_surface(&mesh, &is_edge, 5, &s) > 100);
    let v = mesh.signed_volume();
    assert!((v / sphere_volume(s.r) - 1.0).abs() < 0.03, "{v}");
}

#[test]
fn sphere_adaptive_graded_depth7() {
    let s = sphere();
    let leaves = adaptive_graded(&s, 3, 7);
    assert!(leaves.iter().any(|l| l.depth <= 4) && leaves.iter().any(|l| l.depth == 7));
    let (mesh, is_edge, _) = check_closed("graded", &leaves, 7, &s, 0.0, 1, 2);
    assert!(check_on_surface(&mesh, &is_edge, 7, &s) > 1000);
    let v = mesh.signed_volume();
    assert!((v / sphere_volume(s.r) - 1.0).abs() < 0.02, "{v}");
    let a = mesh.area();
    let exact = 4.0 * std::f64::consts::PI * s.r * s.r;
    assert!((a / exact - 1.0).abs() < 0.02, "{a}");
}

#[test]
fn graded_tree_has_unit_jumps() {
    let s = Sphere {
        c: [0.5, 0.52, 0.49],
        r: 0.25,
    };
    let leaves = adaptive_graded(&s, 2, 5);
    assert_eq!(max_jump(&leaves, 5), 1);
    check_closed("graded small", &leaves, 5, &s, 0.0, 1, 2);
    let leaves = non_graded(&s, 1, 5);
    assert!(max_jump(&leaves, 5) >= 2);
    check_closed("non-graded small", &leaves, 5, &s, 0.0, 1, 2);
}

#[test]
fn sphere_non_graded_depth7() {
    let s = sphere();
    let leaves = non_graded(&s, 2, 7);
    let (mesh, is_edge, _) = check_closed("non-graded", &leaves, 7, &s, 0.0, 1, 2);
    check_on_surface(&mesh, &is_edge, 7, &s);
    let v = mesh.signed_volume();
    assert!((v / sphere_volume(s.r) - 1.0).abs() < 0.02, "{v}");
}

#[test]
fn sphere_random_trees() {
    let s = Sphere {
        c: [0.47, 0.53, 0.5],
        r: 0.27,
    };
    for seed in 0..12 {
        let leaves = random_tree(&s, seed, 6);
        let (mesh, is_edge, _) = check_closed(&format!("random {seed}"), &leaves, 6, &s, 0.0, 1, 2);
        check_on_surface(&mesh, &is_edge, 6, &s);
    }
}

#[test]
fn small_spheres_in_coarse_random_trees() {
    // Features smaller than most cells: many loops bridged along coarse edges.
    for seed in 0..40u64 {
        let r = 0.02 + 0.05 * cell_rand(seed, 99, [1, 2, 3]);
        let c =
            [0.3f64, 0.4, 0.55].map(|x| x + 0.2 * cell_rand(seed, 98, [(x * 100.0) as u32, 0, 0]));
        let s = Sphere { c, r };
        let leaves = leaves_of(&internal_from(6, &|d, o| {
            let (p, w) = center(d, o);
            let q = cell_rand(seed, d, o);
            d < 1 || (s.dist(p) < 1.5 * w && q < 0.6) || q < 0.1
        }));
        let (mesh, n_edge, _) = run(&leaves, 6, &s, 0.0, false);
        // Coarse leaves whose own corners are all outside still carry the crossings of
        // their finer neighbours on their faces: none may be missed.
        let grid = Grid {
            f: &s,
            inv: 1.0 / 64.0,
        };
        assert_eq!(
            n_edge,
            brute_force_crossings(&leaves, 6, &grid, 0.0),
            "seed {seed}: one vertex per crossing finest edge"
        );
        if n_edge == 0 {
            continue;
        }
        let t = mesh.topology();
        assert!(
            t.closed && t.edge_manifold && t.vertex_manifold && t.oriented,
            "seed {seed}: {t:?}"
        );
        assert!(mesh.signed_volume() > 0.0, "seed {seed}");
        // The sampled shape may split into pieces, each a sphere.
        assert_eq!(t.euler, 2 * t.components as i64, "seed {seed}: {t:?}");
    }
}

#[test]
fn torus_all_trees() {
    let t = Torus {
        c: [0.5, 0.49, 0.51],
        big: 0.27,
        small: 0.1,
    };
    check_closed("torus uniform", &uniform(5), 5, &t, 0.0, 1, 0);
    check_closed("torus graded", &adaptive_graded(&t, 3, 7), 7, &t, 0.0, 1, 0);
    check_closed("torus non-graded", &non_graded(&t, 2, 7), 7, &t, 0.0, 1, 0);
    for seed in 0..4 {
        check_closed("torus random", &random_tree(&t, seed, 7), 7, &t, 0.0, 1, 0);
    }
}

#[test]
fn two_spheres() {
    let f = TwoSpheres(
        Sphere {
            c: [0.3, 0.5, 0.5],
            r: 0.15,
        },
        Sphere {
            c: [0.72, 0.51, 0.49],
            r: 0.15,
        },
    );
    check_closed("two uniform", &uniform(5), 5, &f, 0.0, 2, 4);
    let (mesh, _, _) = check_closed("two graded", &adaptive_graded(&f, 3, 7), 7, &f, 0.0, 2, 4);
    let v = mesh.signed_volume();
    assert!((v / (2.0 * sphere_volume(0.15)) - 1.0).abs() < 0.02, "{v}");
    check_closed("two non-graded", &non_graded(&f, 2, 7), 7, &f, 0.0, 2, 4);
    check_closed("two random", &random_tree(&f, 7, 6), 6, &f, 0.0, 2, 4);
}

#[test]
fn iso_value_hits_corners_exactly() {
    // r = 1/4 and c = 1/2 are dyadic: many corners have χ == iso exactly.
    let s = ExactSphere {
        c: [0.5; 3],
        r: 0.25,
    };
    check_closed("exact uniform", &uniform(5), 5, &s, 0.0, 1, 2);
    check_closed("exact graded", &adaptive_graded(&s, 2, 6), 6, &s, 0.0, 1, 2);
    check_closed("exact non-graded", &non_graded(&s, 2, 6), 6, &s, 0.0, 1, 2);
    for seed in 0..4 {
        check_closed("exact random", &random_tree(&s, seed, 6), 6, &s, 0.0, 1, 2);
    }
    // A box whose faces are grid planes full of corners on the iso-value.
    let b = BoxField { h: 0.25 };
    check_closed("box uniform", &uniform(4), 4, &b, 0.0, 1, 2);
    check_closed("box graded", &adaptive_graded(&b, 2, 6), 6, &b, 0.0, 1, 2);
    check_closed("box non-graded", &non_graded(&b, 1, 6), 6, &b, 0.0, 1, 2);
    for seed in 0..4 {
        check_closed("box random", &random_tree(&b, seed, 5), 5, &b, 0.0, 1, 2);
    }
    // Iso-value equal to the value at a set of corners of a general sphere.
    let s = sphere();
    let grid = Grid {
        f: &s,
        inv: 1.0 / 32.0,
    };
    let iso = grid.corner([16, 16, 16], ()).0;
    check_closed("iso at corner", &uniform(5), 5, &s, iso, 1, 2);
}

#[test]
fn sphere_cut_by_the_cube_boundary() {
    let s = Sphere {
        c: [0.5, 0.52, 0.08],
        r: 0.3,
    };
    for (name, leaves, depth) in [
        ("uniform", uniform(5), 5),
        ("graded", adaptive_graded(&s, 3, 7), 7),
        ("non-graded", non_graded(&s, 2, 7), 7),
        ("random", random_tree(&s, 3, 6), 6),
    ] {
        let (mesh, _, is_edge) = run(&leaves, depth, &s, 0.0, false);
        let t = mesh.topology();
        assert!(!t.closed && t.boundary_edges > 0, "{name}: {t:?}");
        assert!(
            t.edge_manifold && t.vertex_manifold && t.oriented,
            "{name}: {t:?}"
        );
        assert_eq!((t.components, t.euler), (1, 1), "{name}: a disk: {t:?}");
        // Boundary vertices lie on the z = 0 face.
        check_on_surface(&mesh, &is_edge, depth, &s);
    }
}

#[test]
fn deepest_supported_depth() {
    // One path refined to depth 18 around a point of the surface, everything else coarse:
    // exercises the full key range and jumps of up to 17 depths.
    let s = sphere();
    let p0 = [s.c[0] + s.r, s.c[1], s.c[2]];
    let q0 = [0.999_999, 0.5, 0.5];
    let s2 = Sphere {
        c: [1.0, 0.5, 0.5],
        r: 0.2,
    };
    for (f, p) in [(&s, p0), (&s2, q0)] {
        let leaves = leaves_of(&internal_from(18, &|d, o| {
            let (c, w) = center(d, o);
            d < 3 || (0..3).all(|i| (p[i] - c[i]).abs() <= 0.5 * w)
        }));
        assert!(leaves.iter().any(|l| l.depth == 18));
        let (mesh, n, _) = run(&leaves, 18, f, 0.0, false);
        assert!(n > 0);
        let t = mesh.topology();
        assert!(t.edge_manifold && t.vertex_manifold && t.oriented, "{t:?}");
        assert_eq!(t.components, 1, "{t:?}");
        if f.c[0] < 0.9 {
            assert!(t.closed && t.euler == 2, "{t:?}");
        } else {
            assert!(!t.closed && t.euler == 1, "{t:?}");
        }
    }
}

#[test]
fn deterministic_across_thread_counts() {
    let s = sphere();
    let leaves = random_tree(&s, 5, 7);
    let grid = Grid {
        f: &s,
        inv: 1.0 / 128.0,
    };
    let go = |n: usize| {
        rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build()
            .unwrap()
            .install(|| extract(&leaves, 7, &grid, 0.0, &ExtractOptions::default()).unwrap())
    };
    let a = go(1);
    let b = go(3);
    assert!(!a.triangles.is_empty());
    assert!(a == b, "meshes differ between 1 and 3 threads");
    assert!(go(2) == a);
}

#[test]
fn leaf_order_does_not_matter_for_topology() {
    let s = sphere();
    let mut leaves = adaptive_graded(&s, 2, 6);
    leaves.reverse();
    check_closed("reversed", &leaves, 6, &s, 0.0, 1, 2);
}

#[test]
fn rejects_bad_input() {
    let s = sphere();
    let grid = Grid {
        f: &s,
        inv: 1.0 / 32.0,
    };
    let o = ExtractOptions::default();
    let mut leaves = uniform(3);
    leaves.pop();
    assert!(extract(&leaves, 5, &grid, 0.0, &o).is_err());
    assert!(extract(&[], 5, &grid, 0.0, &o).is_err());
    assert!(extract(&uniform(1), 19, &grid, 0.0, &o).is_err());
    let bad = vec![
        Leaf {
            depth: 1,
            offset: [2, 0, 0]
        };
        8
    ];
    assert!(extract(&bad, 5, &grid, 0.0, &o).is_err());
    // No surface: empty mesh.
    let m = extract(
        &uniform(2),
        5,
        &Grid {
            f: &BoxField { h: 2.0 },
            inv: 1.0 / 32.0,
        },
        0.0,
        &o,
    )
    .unwrap();
    assert!(m.triangles.is_empty() && m.vertices.is_empty());
}

/// Speed on a large adaptive sphere: `cargo test -p spsr --lib extract::tests::speed --
/// --ignored --nocapture`.
#[test]
#[ignore]
fn speed() {
    let depth: u32 = std::env::var("SPSR_BENCH_DEPTH")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(9);
    let s = sphere();
    let t0 = std::time::Instant::now();
    let leaves = leaves_of(&internal_from(depth, &|d, o| {
        let (p, w) = center(d, o);
        d < 4 || s.dist(p) < (0.87 + 2.0) * w
    }));
    let grid = Grid {
        f: &s,
        inv: 1.0 / (1u64 << depth) as f64,
    };
    let mut hist = vec![0usize; depth as usize + 1];
    for l in &leaves {
        hist[l.depth as usize] += 1;
    }
    eprintln!(
        "tree: {} leaves in {:?}, per depth {hist:?}",
        leaves.len(),
        t0.elapsed()
    );
    for _ in 0..2 {
        let t = std::time::Instant::now();
        let mesh = extract(&leaves, depth, &grid, 0.0, &ExtractOptions::default()).unwrap();
        let dt = t.elapsed().as_secs_f64();
        eprintln!(
            "extract: {:.3}s, {} leaves ({:.2} M/s), {} vertices, {} triangles ({:.2} M/s)",
            dt,
            leaves.len(),
            leaves.len() as f64 / dt * 1e-6,
            mesh.vertices.len(),
            mesh.triangles.len(),
            mesh.triangles.len() as f64 / dt * 1e-6
        );
        let t = std::time::Instant::now();
        let topo = mesh.topology();
        eprintln!("topology {:?}: {topo:?}", t.elapsed());
        assert!(topo.closed && topo.vertex_manifold && topo.oriented && topo.euler == 2);
    }
}

/// The values of an analytic field at the finest grid's corners, taken as a field trilinear
/// on the grid's cells, with the corner gradient a degree-1 solution hands over: the mean of
/// the one-sided derivatives (one-sided at the cube's faces). With `trilinear` it says so,
/// and extraction reads the slopes from the neighbouring corners' values instead.
struct Interpolated<'a> {
    f: &'a dyn Analytic,
    depth: u32,
    trilinear: bool,
}

impl Interpolated<'_> {
    fn at(&self, c: [u32; 3]) -> f64 {
        self.f
            .eval(c.map(|x| x as f64 / (1u64 << self.depth) as f64))
            .0
    }
}

impl Field for Interpolated<'_> {
    fn corner(&self, c: [u32; 3], _near: ()) -> (f64, [f64; 3]) {
        let full = 1u32 << self.depth;
        let per_cell = f64::from(full);
        let here = self.at(c);
        let grad = std::array::from_fn(|a| {
            let moved = |up: bool| {
                let mut p = c;
                p[a] = if up { p[a] + 1 } else { p[a] - 1 };
                self.at(p)
            };
            match (c[a] > 0, c[a] < full) {
                (true, true) => 0.5 * (moved(true) - moved(false)) * per_cell,
                (false, true) => (moved(true) - here) * per_cell,
                (true, false) => (here - moved(false)) * per_cell,
                (false, false) => 0.0,
            }
        });
        (here, grad)
    }

    fn value(&self, c: [u32; 3], _near: ()) -> f64 {
        self.at(c)
    }

    fn trilinear(&self) -> bool {
        self.trilinear
    }
}

#[test]
fn slopes_from_neighbouring_corners_match_the_corner_gradients() {
    // On adaptive trees, where many neighbours of a crossing's corners are no leaf's corner,
    // and with normals (every axis's slope): the same mesh, bit for bit (iso 0, so the
    // differences of `χ − iso` are those of χ).
    let s = sphere();
    for (name, leaves) in [
        ("graded", adaptive_graded(&s, 2, 6)),
        ("random", random_tree(&s, 7, 6)),
    ] {
        let opts = ExtractOptions {
            normals: true,
            ..Default::default()
        };
        let mesh = |trilinear| {
            let field = Interpolated {
                f: &s,
                depth: 6,
                trilinear,
            };
            extract(&leaves, 6, &field, 0.0, &opts).unwrap()
        };
        let (given, read) = (mesh(false), mesh(true));
        assert!(given.triangles.len() > 1000, "{name}");
        assert_eq!(given.vertices, read.vertices, "{name}");
        assert_eq!(given.triangles, read.triangles, "{name}");
        assert_eq!(given.normals, read.normals, "{name}");
    }
}
