//! The fuzz targets' bodies. Also compiled into spsr's test suite (included by
//! `crates/spsr/tests/common/mod.rs`; `tests/io/fuzz_regressions.rs` replays the inputs in
//! `fuzz/regressions/<target>/`), so keep it to `spsr`, `tempfile` and `std`.
//!
//! A target returns normally for every input: readers may fail with an error (that is what
//! hostile input should get), but a panic, an abort, a hang or an invariant violation
//! (checked here with `assert!`) is a finding.

use spsr::{Boundary, Degree, Mesh, Params, PointCloud, PointWeights};

/// The input written to a temporary file with the given extension (the readers take paths,
/// as users' files do, so the targets go through exactly the code users run). The file is
/// removed when the returned handle is dropped, so neither fuzzing nor the test suite's
/// replays leave anything behind.
fn input_file(ext: &str, data: &[u8]) -> tempfile::NamedTempFile {
    let mut f = tempfile::Builder::new()
        .prefix("spsr-fuzz-")
        .suffix(&format!(".{ext}"))
        .tempfile()
        .expect("a temporary file for the fuzz input");
    std::io::Write::write_all(&mut f, data).expect("write the fuzz input");
    f
}

/// Checks what a reader promises about a cloud it returns.
pub fn check_cloud(c: &PointCloud) {
    let n = c.positions.len();
    assert!(
        c.normals.is_empty() || c.normals.len() == n,
        "normals per point"
    );
    for a in &c.attributes {
        assert_eq!(a.len(), n, "attribute {} has one value per point", a.name);
    }
    assert!(
        c.scan_origins
            .windows(2)
            .all(|w| w[0].first_point <= w[1].first_point),
        "scan origins sorted"
    );
}

/// Checks what a mesh reader or `reconstruct` promises about a mesh.
pub fn check_mesh(m: &Mesh) {
    let n = m.vertices.len();
    assert!(
        m.triangles
            .iter()
            .all(|t| t.iter().all(|&i| (i as usize) < n)),
        "triangle indices in range"
    );
    if let Some(d) = &m.density {
        assert_eq!(d.len(), n, "density per vertex");
    }
    if let Some(nr) = &m.normals {
        assert_eq!(nr.len(), n, "normals per vertex");
    }
    for a in &m.attributes {
        assert_eq!(a.len(), n, "attribute {} per vertex", a.name);
    }
}

fn read_cloud_as(data: &[u8], ext: &str) {
    let input = input_file(ext, data);
    let path = input.path();
    if let Ok(c) = spsr::io::read_cloud(path) {
        check_cloud(&c);
    }
    // The oriented-points entry refuses clouds without normals early; same invariants.
    if let Ok(c) = spsr::io::read_points(path) {
        check_cloud(&c);
        assert!(c.normals.len() == c.positions.len());
    }
}

/// PLY point clouds: ASCII and binary (the header chooses).
pub fn ply(data: &[u8]) {
    read_cloud_as(data, "ply");
}

/// PLY meshes (`spsr trim`, `spsr eval`).
pub fn ply_mesh(data: &[u8]) {
    let input = input_file("ply", data);
    let path = input.path();
    if let Ok(m) = spsr::io::read_mesh(path) {
        check_mesh(&m);
        // What `spsr eval` and `spsr trim` do next with a mesh read from a file.
        let _ = m.topology();
        let _ = m.area();
        if m.density.is_some() {
            let _ = spsr::trim::trim(&m, &spsr::trim::TrimParams::default());
        }
    }
}

/// The other mesh readers (OBJ, STL, OFF, GLB: `spsr eval` and `spsr trim`, and mesh files
/// read as clouds): the input under each extension, so that the formats without magic bytes
/// (OBJ, binary STL) are reached too.
pub fn mesh(data: &[u8]) {
    for ext in ["obj", "stl", "off", "glb"] {
        let input = input_file(ext, data);
        let path = input.path();
        if let Ok(m) = spsr::io::read_mesh(path) {
            check_mesh(&m);
            let _ = m.topology();
            let _ = m.area();
        }
        if let Ok(c) = spsr::io::read_cloud(path) {
            check_cloud(&c);
        }
    }
}

/// Text point clouds.
pub fn text(data: &[u8]) {
    read_cloud_as(data, "xyz");
}

/// LAS and LAZ (the reader is the same; LAZ is told apart by the header's point format).
pub fn las(data: &[u8]) {
    read_cloud_as(data, "las");
}

/// E57.
pub fn e57(data: &[u8]) {
    read_cloud_as(data, "e57");
}

/// PCD: ASCII, binary and binary_compressed.
pub fn pcd(data: &[u8]) {
    read_cloud_as(data, "pcd");
}

/// Most points a `reconstruct` input gets.
const MAX_POINTS: usize = 256;

/// The parameters and the cloud a `reconstruct` input describes: 4 bytes of parameters,
/// then points, as 6 raw little-endian `f32` (any bit pattern: NaN, infinities, 1e38, ...)
/// or as 6 `i8` on a grid of step 1/8 (duplicates, planes, lines, opposite normals).
pub fn decode_reconstruct(data: &[u8]) -> Option<(Params, PointCloud)> {
    if data.len() < 4 {
        return None;
    }
    let (head, body) = data.split_at(4);
    let depth = 1 + u32::from(head[0] % 6);
    let flags = head[1];
    let mode = head[2];
    let params = Params {
        depth,
        full_depth: u32::from(head[3] % 7).min(depth),
        degree: if flags & 1 == 0 {
            Degree::Linear
        } else {
            Degree::Quadratic
        },
        boundary: [Boundary::Neumann, Boundary::Dirichlet, Boundary::Free]
            [usize::from((flags >> 1) % 4 % 3)],
        weights: if flags & 8 != 0 {
            PointWeights::NormalLength
        } else {
            PointWeights::Uniform
        },
        two_level_splat: flags & 16 != 0,
        linear_fit: flags & 32 != 0,
        density: flags & 64 != 0,
        normals: flags & 128 != 0,
        samples_per_node: [1.5, 1.0, 0.5, 8.0][usize::from(mode & 3)],
        scale: [1.1, 1.0, 2.0, 1.1][usize::from((mode >> 3) & 3)],
        max_memory: Some(1 << 30),
        ..Params::default()
    };
    let raw = mode & 4 != 0;
    let mut positions = Vec::new();
    let mut normals = Vec::new();
    if raw {
        for rec in body.chunks_exact(24).take(MAX_POINTS) {
            let f = |k: usize| {
                f64::from(f32::from_le_bytes(
                    rec[4 * k..4 * k + 4].try_into().unwrap(),
                ))
            };
            positions.push([f(0), f(1), f(2)]);
            normals.push([f(3), f(4), f(5)]);
        }
    } else {
        for rec in body.chunks_exact(6).take(MAX_POINTS) {
            let f = |k: usize| f64::from(rec[k] as i8) / 8.0;
            positions.push([f(0), f(1), f(2)]);
            normals.push([f(3), f(4), f(5)]);
        }
    }
    Some((params, PointCloud::new(positions, normals).ok()?))
}

/// `reconstruct` on tiny clouds with varied parameters: an error is fine, a panic or a mesh
/// with non-finite values, bad indices or holes is not.
pub fn reconstruct(data: &[u8]) {
    let Some((params, cloud)) = decode_reconstruct(data) else {
        return;
    };
    match spsr::reconstruct(&cloud, &params) {
        Ok(r) => {
            let m = &r.mesh;
            check_mesh(m);
            assert!(
                m.vertices.iter().flatten().all(|v| v.is_finite()),
                "finite vertices"
            );
            if let Some(d) = &m.density {
                assert!(d.iter().all(|v| v.is_finite()), "finite density");
            }
            if let Some(n) = &m.normals {
                assert!(n.iter().flatten().all(|v| v.is_finite()), "finite normals");
            }
            let t = m.topology();
            assert!(t.edge_manifold, "manifold mesh: {t:?}");
            let open = open_edges_inside_cube(m, &cloud, &params);
            assert_eq!(
                open, 0,
                "closed mesh (boundary only on the bounding cube): {t:?}"
            );
        }
        Err(e) => {
            // Every error has a message.
            assert!(!e.to_string().is_empty());
        }
    }
}

/// Edges used by one triangle that do not lie on a face of the bounding cube. The surface is
/// extracted inside the cube, so where the implicit surface reaches the cube's faces the mesh
/// is cut open there (as PoissonRecon's is); anywhere else it must be closed.
pub fn open_edges_inside_cube(m: &Mesh, cloud: &PointCloud, params: &Params) -> usize {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for (p, n) in cloud.positions.iter().zip(&cloud.normals) {
        if spsr::points::is_valid(p, n) {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
    }
    let side = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
    let width = side * params.scale;
    let face_lo: [f64; 3] = std::array::from_fn(|a| 0.5 * (lo[a] + hi[a]) - 0.5 * width);
    let tol = 1e-6 * width;
    let on_face = |p: [f64; 3], a: usize| {
        (p[a] - face_lo[a]).abs() <= tol || (p[a] - face_lo[a] - width).abs() <= tol
    };
    let mut edges = std::collections::HashMap::new();
    for t in &m.triangles {
        for k in 0..3 {
            let (i, j) = (t[k], t[(k + 1) % 3]);
            *edges.entry((i.min(j), i.max(j))).or_insert(0u32) += 1;
        }
    }
    edges
        .iter()
        .filter(|&(&(i, j), &c)| {
            let (p, q) = (m.vertices[i as usize], m.vertices[j as usize]);
            c == 1 && !(0..3).any(|a| on_face(p, a) && on_face(q, a))
        })
        .count()
}
