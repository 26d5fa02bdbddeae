//! Mesh evaluation (`spsr::metrics::evaluate`) on inputs whose scores can be derived by hand:
//! concentric spheres, a cube against a shifted copy, a mesh against itself, the analytic
//! sphere, topology flags, errors and thread-count independence.

use std::collections::HashMap;
use std::time::Instant;

use spsr::metrics::{evaluate, EvalOptions, Evaluation, Reference};
use spsr::{Error, Mesh};

/// Icosphere of the given radius and centre: an icosahedron subdivided `level` times, every
/// vertex on the sphere (20 · 4^level faces, counter-clockwise seen from outside).
fn icosphere(center: [f64; 3], radius: f64, level: u32) -> Mesh {
    let t = (1.0 + 5f64.sqrt()) / 2.0;
    let mut vertices: Vec<[f64; 3]> = vec![
        [-1.0, t, 0.0],
        [1.0, t, 0.0],
        [-1.0, -t, 0.0],
        [1.0, -t, 0.0],
        [0.0, -1.0, t],
        [0.0, 1.0, t],
        [0.0, -1.0, -t],
        [0.0, 1.0, -t],
        [t, 0.0, -1.0],
        [t, 0.0, 1.0],
        [-t, 0.0, -1.0],
        [-t, 0.0, 1.0],
    ];
    let unit = |v: [f64; 3]| {
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        [v[0] / l, v[1] / l, v[2] / l]
    };
    for v in &mut vertices {
        *v = unit(*v);
    }
    let mut triangles: Vec<[u32; 3]> = vec![
        [0, 11, 5],
        [0, 5, 1],
        [0, 1, 7],
        [0, 7, 10],
        [0, 10, 11],
        [1, 5, 9],
        [5, 11, 4],
        [11, 10, 2],
        [10, 7, 6],
        [7, 1, 8],
        [3, 9, 4],
        [3, 4, 2],
        [3, 2, 6],
        [3, 6, 8],
        [3, 8, 9],
        [4, 9, 5],
        [2, 4, 11],
        [6, 2, 10],
        [8, 6, 7],
        [9, 8, 1],
    ];
    for _ in 0..level {
        let mut mid: HashMap<(u32, u32), u32> = HashMap::new();
        let mut next = Vec::with_capacity(triangles.len() * 4);
        for &[a, b, c] in &triangles {
            let mut m = |x: u32, y: u32| {
                *mid.entry((x.min(y), x.max(y))).or_insert_with(|| {
                    let (p, q) = (vertices[x as usize], vertices[y as usize]);
                    vertices.push(unit([p[0] + q[0], p[1] + q[1], p[2] + q[2]]));
                    vertices.len() as u32 - 1
                })
            };
            let (ab, bc, ca) = (m(a, b), m(b, c), m(c, a));
            next.extend([[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]);
        }
        triangles = next;
    }
    let vertices = vertices
        .into_iter()
        .map(|v| std::array::from_fn(|k| center[k] + radius * v[k]))
        .collect();
    Mesh {
        vertices,
        triangles,
        ..Default::default()
    }
}

/// UV sphere of radius `r` at the origin: `nlat` rings of latitude, `nlon` segments
/// (2 · nlon · (nlat − 1) faces).
fn uv_sphere(r: f64, nlat: usize, nlon: usize) -> Mesh {
    let mut vertices = vec![[0.0, 0.0, r]];
    for i in 1..nlat {
        let th = std::f64::consts::PI * i as f64 / nlat as f64;
        for j in 0..nlon {
            let ph = 2.0 * std::f64::consts::PI * j as f64 / nlon as f64;
            vertices.push([
                r * th.sin() * ph.cos(),
                r * th.sin() * ph.sin(),
                r * th.cos(),
            ]);
        }
    }
    vertices.push([0.0, 0.0, -r]);
    let south = vertices.len() as u32 - 1;
    let id = |i: usize, j: usize| (1 + (i - 1) * nlon + j % nlon) as u32;
    let mut triangles = Vec::new();
    for j in 0..nlon {
        triangles.push([0, id(1, j), id(1, j + 1)]);
        triangles.push([south, id(nlat - 1, j + 1), id(nlat - 1, j)]);
    }
    for i in 1..nlat - 1 {
        for j in 0..nlon {
            triangles.push([id(i, j), id(i + 1, j), id(i + 1, j + 1)]);
            triangles.push([id(i, j), id(i + 1, j + 1), id(i, j + 1)]);
        }
    }
    Mesh {
        vertices,
        triangles,
        ..Default::default()
    }
}

/// The unit cube `[0, 1]³` shifted by `dx` along x, two outward triangles per face.
fn cube(dx: f64) -> Mesh {
    let vertices = (0..8)
        .map(|i| {
            [
                (i & 1) as f64 + dx,
                ((i >> 1) & 1) as f64,
                ((i >> 2) & 1) as f64,
            ]
        })
        .collect();
    let quads = [
        [0, 4, 6, 2], // x = 0
        [1, 3, 7, 5], // x = 1
        [0, 1, 5, 4], // y = 0
        [2, 6, 7, 3], // y = 1
        [0, 2, 3, 1], // z = 0
        [4, 5, 7, 6], // z = 1
    ];
    let triangles = quads
        .iter()
        .flat_map(|q| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    Mesh {
        vertices,
        triangles,
        ..Default::default()
    }
}

fn opts(samples: usize) -> EvalOptions {
    EvalOptions {
        samples,
        ..EvalOptions::default()
    }
}

/// Smallest distance from the centre to a face plane of a sphere mesh whose vertices lie on
/// the sphere (the tessellation's worst inset: 1 − this is the largest sagitta).
fn min_plane_distance(mesh: &Mesh, center: [f64; 3]) -> f64 {
    mesh.triangles
        .iter()
        .map(|t| {
            let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
            let n = spsr::metrics::triangle_normal(a, b, c);
            (0..3).map(|k| n[k] * (a[k] - center[k])).sum::<f64>()
        })
        .fold(f64::INFINITY, f64::min)
}

fn close(a: f64, b: f64, tol: f64) -> bool {
    (a - b).abs() <= tol
}

#[test]
fn concentric_spheres_are_a_tenth_apart() {
    let inner = icosphere([0.0; 3], 1.0, 4);
    let outer = icosphere([0.0; 3], 1.1, 4);
    // Both are convex polyhedra, scaled copies of each other. A point of the inner one lies
    // at 0.1·h_F from the outer face plane above it and no nearer than 0.1·h_min to any outer
    // plane; a point x of the outer one is within |x|·0.1/1.1 ≤ 0.1 of x/1.1 on the inner one
    // and at least 0.1·h_min from it. So every distance lies in [0.1·h_min, 0.1].
    let h_min = min_plane_distance(&inner, [0.0; 3]);
    assert!(h_min > 0.99 && h_min < 1.0, "{h_min}");
    let (lo, hi) = (0.1 * h_min - 1e-12, 0.1 + 1e-12);
    let e = evaluate(&inner, &Reference::Mesh(outer), &opts(100_000)).unwrap();
    for d in [
        e.chamfer,
        e.hausdorff,
        e.mesh_to_reference.mean,
        e.reference_to_mesh.mean,
        e.mesh_to_reference.max,
        e.reference_to_mesh.max,
    ] {
        assert!(d >= lo && d <= hi, "{d} not in [{lo}, {hi}]: {e:?}");
    }
    let diag = 2.2 * 3f64.sqrt();
    assert!(close(e.diagonal, diag, 1e-12));
    assert!(close(e.chamfer_rel, e.chamfer / diag, 1e-15));
    assert!(close(e.hausdorff_rel, e.hausdorff / diag, 1e-15));
    // 1 % of the diagonal is 0.038 < 0.099: nothing is within either threshold.
    assert_eq!(e.fscore_0_5.fscore, 0.0);
    assert_eq!(e.fscore_1.fscore, 0.0);
    assert!(close(e.fscore_1.threshold, 0.01 * diag, 1e-12));
    // Closest faces are the same or adjacent faces: nearly parallel.
    assert!(e.normal_consistency > 0.99 && e.normal_consistency <= 1.0 + 1e-12);
    let t = e.topology;
    assert!(t.closed && t.edge_manifold && t.vertex_manifold && t.oriented);
    assert_eq!(
        (t.faces, t.vertices, t.components, t.euler),
        (5120, 2562, 1, 2)
    );
}

#[test]
fn uv_spheres_too() {
    let inner = uv_sphere(1.0, 60, 120);
    let outer = uv_sphere(1.1, 60, 120);
    let h_min = min_plane_distance(&inner, [0.0; 3]);
    let e = evaluate(&outer, &Reference::Mesh(inner), &opts(50_000)).unwrap();
    for d in [e.chamfer, e.hausdorff] {
        assert!(d >= 0.1 * h_min - 1e-12 && d <= 0.1 + 1e-12, "{d}");
    }
}

#[test]
fn cube_against_a_shifted_cube() {
    // Cube A = [0,1]³, B = A + (s, 0, 0). From A's surface to B's (by symmetry the same the
    // other way): the face x = 0 is at distance s; the face x = 1 lies inside B, at
    // min(s, distance to the square's border) from B's surface, whose mean is
    // ∫₀ˢ (1 − 2t)² dt = (1 − (1 − 2s)³)/6; on each of the four side faces the part x < s is at
    // s − x, the rest on B's surface: mean s²/2. Faces have area 1 of 6.
    let s: f64 = 0.25;
    let expected = (s + (1.0 - (1.0 - 2.0 * s).powi(3)) / 6.0 + 4.0 * s * s / 2.0) / 6.0;
    let e = evaluate(&cube(0.0), &Reference::Mesh(cube(s)), &opts(400_000)).unwrap();
    assert!(close(e.mesh_to_reference.mean, expected, 1e-3), "{e:?}");
    assert!(close(e.reference_to_mesh.mean, expected, 1e-3), "{e:?}");
    assert!(close(e.chamfer, expected, 1e-3));
    // Every point of A's face x = 0 is exactly s away, and nothing is farther.
    assert!(close(e.hausdorff, s, 1e-12), "{}", e.hausdorff);
    assert!(close(e.hausdorff_rel, s / 3f64.sqrt(), 1e-12));
    // Within τ: on x = 1 where the border distance ≤ τ, 1 − (1 − 2τ)²; on the side faces the
    // part x ≥ s − τ, 1 − s + τ; on x = 0 nothing.
    for (f, frac) in [(e.fscore_0_5, 0.005), (e.fscore_1, 0.01)] {
        let tau = frac * 3f64.sqrt();
        let p = ((1.0 - (1.0 - 2.0 * tau).powi(2)) + 4.0 * (1.0 - s + tau)) / 6.0;
        assert!(close(f.threshold, tau, 1e-12));
        assert!(close(f.precision, p, 3e-3), "{f:?} vs {p}");
        assert!(close(f.recall, p, 3e-3), "{f:?} vs {p}");
        assert!(close(f.fscore, p, 3e-3), "{f:?} vs {p}");
    }
}

#[test]
fn a_mesh_against_itself_scores_perfectly() {
    for (mesh, nc) in [
        (cube(0.0), 1.0 - 1e-9),
        (icosphere([0.5, -1.0, 2.0], 0.7, 3), 0.999),
    ] {
        let e = evaluate(&mesh, &Reference::Mesh(mesh.clone()), &opts(100_000)).unwrap();
        assert!(e.chamfer < 1e-12 && e.hausdorff < 1e-12, "{e:?}");
        assert!(e.chamfer_rel < 1e-12 && e.hausdorff_rel < 1e-12);
        assert_eq!(e.fscore_0_5.fscore, 1.0);
        assert_eq!(e.fscore_1.fscore, 1.0);
        assert_eq!(e.fscore_1.precision, 1.0);
        assert_eq!(e.fscore_1.recall, 1.0);
        assert!(e.normal_consistency > nc && e.normal_consistency <= 1.0 + 1e-12);
        assert!(close(e.area, e.reference_area, 1e-12));
        assert!(e.topology.closed);
    }
}

#[test]
fn analytic_sphere_against_a_fine_sphere_mesh() {
    let center = [1.0, 2.0, 3.0];
    let mesh = icosphere(center, 1.0, 6);
    // Mesh points lie between the face planes and the sphere: within 1 − h_min of it; the
    // sphere's points are within the same distance of the (convex, inscribed) mesh.
    let sag = 1.0 - min_plane_distance(&mesh, center);
    assert!(sag > 0.0 && sag < 1e-3, "{sag}");
    let sphere = Reference::Sphere {
        center,
        radius: 1.0,
    };
    let e = evaluate(&mesh, &sphere, &opts(200_000)).unwrap();
    assert!(
        e.hausdorff <= sag + 1e-12 && e.chamfer <= sag,
        "{e:?} {sag}"
    );
    // The mean deviation of a flat triangle from its sphere is a fraction of the sagitta.
    assert!(e.chamfer > 0.1 * sag, "{e:?} {sag}");
    assert!(close(e.diagonal, 2.0 * 3f64.sqrt(), 1e-12));
    assert!(close(e.reference_area, 4.0 * std::f64::consts::PI, 1e-12));
    assert!(e.area < e.reference_area && e.area > 0.99 * e.reference_area);
    assert_eq!(e.fscore_0_5.fscore, 1.0);
    assert!(e.normal_consistency > 0.999, "{e:?}");

    // The same against a mesh of the sphere gives nearly the same numbers.
    let fine = icosphere(center, 1.0, 7);
    let m = evaluate(&mesh, &Reference::Mesh(fine), &opts(200_000)).unwrap();
    assert!(
        close(m.chamfer, e.chamfer, 0.3 * e.chamfer),
        "{m:?} vs {e:?}"
    );

    // A sphere mesh of radius 1.05 against the unit sphere: 0.05 minus the sagitta.
    let big = icosphere(center, 1.05, 6);
    let e = evaluate(&big, &sphere, &opts(100_000)).unwrap();
    assert!(e.chamfer > 0.05 - 1.05 * sag - 1e-12 && e.chamfer <= 0.05 + 1e-12);
    // The vertices are exactly 0.05 away; the largest sampled distance comes close to that.
    assert!(
        e.hausdorff > 0.05 - 1e-4 && e.hausdorff <= 0.05 + 1e-12,
        "{e:?}"
    );
}

#[test]
fn open_and_non_manifold_meshes_are_reported() {
    let mut open = cube(0.0);
    open.triangles.truncate(10); // drop the face z = 1
    let e = evaluate(&open, &Reference::Mesh(cube(0.0)), &opts(20_000)).unwrap();
    let t = e.topology;
    assert!(!t.closed && t.edge_manifold && t.vertex_manifold && t.oriented);
    assert_eq!((t.boundary_edges, t.euler, t.components), (4, 1, 1));
    // The open cube lies on the closed one; the missing face is 0.5 away at most.
    assert!(e.mesh_to_reference.mean < 1e-12);
    assert!(e.reference_to_mesh.mean > 0.01 && close(e.hausdorff, 0.5, 0.01));

    let mut fin = cube(0.0);
    // A fin on the cube's bottom edge y = 0, z = 0: a third triangle on that edge.
    fin.vertices.push([0.5, -1.0, -1.0]);
    fin.triangles.push([0, 1, 8]);
    let e = evaluate(&fin, &Reference::Mesh(cube(0.0)), &opts(20_000)).unwrap();
    let t = e.topology;
    assert!(!t.edge_manifold && !t.closed);
    assert_eq!(t.non_manifold_edges, 1);
    assert_eq!(t.components, 1);
}

#[test]
fn bad_inputs_are_errors() {
    let good = cube(0.0);
    let reference = Reference::Mesh(good.clone());
    let empty = Mesh::default();
    assert!(matches!(
        evaluate(&empty, &reference, &opts(10)),
        Err(Error::Degenerate(m)) if m.contains("mesh has no triangles")
    ));
    assert!(matches!(
        evaluate(&good, &Reference::Mesh(empty), &opts(10)),
        Err(Error::Degenerate(m)) if m.contains("reference mesh has no triangles")
    ));
    let flat = Mesh {
        vertices: vec![[0.0; 3], [1.0, 0.0, 0.0], [2.0, 0.0, 0.0]],
        triangles: vec![[0, 1, 2]],
        ..Default::default()
    };
    assert!(matches!(
        evaluate(&flat, &reference, &opts(10)),
        Err(Error::Degenerate(m)) if m.contains("no area")
    ));
    let mut nan = good.clone();
    nan.vertices[3][1] = f64::NAN;
    assert!(matches!(
        evaluate(&nan, &reference, &opts(10)),
        Err(Error::Degenerate(m)) if m.contains("non-finite")
    ));
    let mut bad_index = good.clone();
    bad_index.triangles[0][2] = 8;
    assert!(evaluate(&bad_index, &reference, &opts(10)).is_err());
    assert!(matches!(
        evaluate(&good, &reference, &opts(0)),
        Err(Error::InvalidParameter {
            field: "samples",
            ..
        })
    ));
    for (center, radius) in [
        ([0.0; 3], 0.0),
        ([0.0; 3], -1.0),
        ([f64::NAN, 0.0, 0.0], 1.0),
    ] {
        assert!(matches!(
            evaluate(&good, &Reference::Sphere { center, radius }, &opts(10)),
            Err(Error::InvalidParameter {
                field: "reference_sphere",
                ..
            })
        ));
    }
}

#[test]
fn results_do_not_depend_on_the_thread_count() {
    let mesh = uv_sphere(1.0, 80, 160);
    let refs = [
        Reference::Mesh(icosphere([0.01, 0.0, 0.0], 1.02, 4)),
        Reference::Sphere {
            center: [0.0, 0.01, 0.0],
            radius: 0.98,
        },
    ];
    for reference in &refs {
        let run = |threads: usize| -> Evaluation {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| evaluate(&mesh, reference, &opts(100_000)).unwrap())
        };
        let one = run(1);
        assert_eq!(one, run(3));
        assert_eq!(one.to_json(), run(3).to_json());
    }
}

#[test]
fn json_has_every_key() {
    let e = evaluate(&cube(0.0), &Reference::Mesh(cube(0.1)), &opts(1000)).unwrap();
    let json = e.to_json();
    assert!(json.starts_with('{') && json.ends_with('}') && !json.contains('\n'));
    for key in [
        "chamfer",
        "chamfer_rel",
        "hausdorff",
        "hausdorff_rel",
        "mesh_to_reference_mean",
        "reference_to_mesh_mean",
        "fscore_0_5",
        "fscore_1",
        "normal_consistency",
        "vertices",
        "faces",
        "components",
        "euler",
    ] {
        assert!(json.contains(&format!("\"{key}\": ")), "{key} in {json}");
    }
    for key in ["closed", "edge_manifold", "vertex_manifold", "oriented"] {
        assert!(
            json.contains(&format!("\"{key}\": true")),
            "{key} in {json}"
        );
    }
    assert!(!json.contains("null") && !json.contains("NaN") && !json.contains("inf"));
}

/// Speed on about two million faces with one million samples per surface:
/// `cargo test -p spsr --test io -- --ignored --nocapture speed_two_million_faces`.
#[test]
#[ignore]
fn speed_two_million_faces() {
    let t = Instant::now();
    let mesh = uv_sphere(1.0, 1000, 1000);
    let reference = icosphere([0.0; 3], 1.003, 8);
    println!(
        "generated {} and {} faces in {:.2} s",
        mesh.triangles.len(),
        reference.triangles.len(),
        t.elapsed().as_secs_f64()
    );
    let t = Instant::now();
    let tree = spsr::metrics::MeshDistance::new(&mesh);
    println!(
        "hierarchy over {} faces: {:.2} s",
        mesh.triangles.len(),
        t.elapsed().as_secs_f64()
    );
    drop(tree);
    let o = EvalOptions::default();
    let t = Instant::now();
    let e = evaluate(&mesh, &Reference::Mesh(reference), &o).unwrap();
    println!(
        "mesh reference: {:.2} s, {} samples per surface, chamfer {:e}, hausdorff {:e}",
        t.elapsed().as_secs_f64(),
        o.samples,
        e.chamfer,
        e.hausdorff
    );
    let t = Instant::now();
    let sphere = Reference::Sphere {
        center: [0.0; 3],
        radius: 1.0,
    };
    let e = evaluate(&mesh, &sphere, &o).unwrap();
    println!(
        "sphere reference: {:.2} s, chamfer {:e}, hausdorff {:e}",
        t.elapsed().as_secs_f64(),
        e.chamfer,
        e.hausdorff
    );
}
