//! Benchmark peer: reconstructs a mesh from an oriented point cloud with the crates.io crate
//! `poisson_reconstruction` and writes it as binary PLY.
//!
//! ```text
//! poisson_reconstruction_runner IN.ply OUT.ply DEPTH SCREENING THREADS [DENSITY_DEPTH] [ITERS]
//! ```
//!
//! IN.ply: binary little-endian PLY whose `vertex` element has float (float32) properties
//! including x y z nx ny nz (the format of `../shared/data` and of the harness's own inputs).
//! DENSITY_DEPTH defaults to DEPTH - 2 (PoissonRecon's kernel depth); ITERS (the crate's
//! conjugate-gradient iterations per level) defaults to 10, the crate's recommendation.
//! Prints `compute_seconds S` (reconstruction and extraction, without I/O) to stderr.
use std::error::Error;
use std::fs::File;
use std::io::{BufRead, BufReader, BufWriter, Read, Write};
use std::time::Instant;

use nalgebra::{Point3, Vector3};
use poisson_reconstruction::PoissonReconstruction;

type Points = (Vec<Point3<f64>>, Vec<Vector3<f64>>);

fn read_points(path: &str) -> Result<Points, Box<dyn Error>> {
    let mut r = BufReader::new(File::open(path)?);
    let mut line = String::new();
    let (mut count, mut in_vertex, mut binary_le) = (None, false, false);
    let mut props: Vec<String> = Vec::new();
    loop {
        line.clear();
        if r.read_line(&mut line)? == 0 {
            return Err("PLY header has no end_header".into());
        }
        let words: Vec<&str> = line.split_whitespace().collect();
        match words.as_slice() {
            ["format", "binary_little_endian", _] => binary_le = true,
            ["element", "vertex", n] => {
                count = Some(n.parse::<usize>()?);
                in_vertex = true;
            }
            ["element", ..] => in_vertex = false,
            ["property", "float", name] if in_vertex => props.push(name.to_string()),
            ["property", ..] if in_vertex => {
                return Err(format!("unsupported vertex property: {}", line.trim()).into())
            }
            ["end_header"] => break,
            _ => {}
        }
    }
    if !binary_le {
        return Err("only binary little-endian PLY is supported".into());
    }
    let count = count.ok_or("PLY has no vertex element")?;
    let index = |name: &str| {
        props
            .iter()
            .position(|p| p == name)
            .ok_or_else(|| format!("PLY vertex has no property {name}"))
    };
    let idx = [
        index("x")?,
        index("y")?,
        index("z")?,
        index("nx")?,
        index("ny")?,
        index("nz")?,
    ];
    let mut buf = vec![0u8; count * props.len() * 4];
    r.read_exact(&mut buf)?;
    let mut points = Vec::with_capacity(count);
    let mut normals = Vec::with_capacity(count);
    for rec in buf.chunks_exact(props.len() * 4) {
        let f = |i: usize| f32::from_le_bytes(rec[4 * i..4 * i + 4].try_into().unwrap()) as f64;
        points.push(Point3::new(f(idx[0]), f(idx[1]), f(idx[2])));
        normals.push(Vector3::new(f(idx[3]), f(idx[4]), f(idx[5])));
    }
    Ok((points, normals))
}

fn write_mesh(path: &str, vertices: &[Point3<f64>], indices: &[u32]) -> std::io::Result<()> {
    let mut w = BufWriter::new(File::create(path)?);
    write!(
        w,
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\nelement face {}\n\
         property list uchar int vertex_indices\nend_header\n",
        vertices.len(),
        indices.len() / 3
    )?;
    for v in vertices {
        for c in [v.x, v.y, v.z] {
            w.write_all(&(c as f32).to_le_bytes())?;
        }
    }
    for tri in indices.chunks_exact(3) {
        w.write_all(&[3u8])?;
        for &i in tri {
            w.write_all(&(i as i32).to_le_bytes())?;
        }
    }
    w.flush()
}

fn main() -> Result<(), Box<dyn Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 6 {
        return Err(
            "usage: poisson_reconstruction_runner IN.ply OUT.ply DEPTH SCREENING \
                    THREADS [DENSITY_DEPTH] [ITERS]"
                .into(),
        );
    }
    let depth: usize = args[3].parse()?;
    let screening: f64 = args[4].parse()?;
    let threads: usize = args[5].parse()?;
    let density_depth: usize = match args.get(6) {
        Some(s) => s.parse()?,
        None => depth.saturating_sub(2),
    };
    let iters: usize = match args.get(7) {
        Some(s) => s.parse()?,
        None => 10,
    };
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global()?;
    let (points, normals) = read_points(&args[1])?;
    let start = Instant::now();
    let poisson = PoissonReconstruction::from_points_and_normals(
        &points,
        &normals,
        screening,
        density_depth,
        depth,
        iters,
    );
    let mesh = poisson.reconstruct_mesh_buffers();
    let seconds = start.elapsed().as_secs_f64();
    write_mesh(&args[2], mesh.vertices(), mesh.indices())?;
    eprintln!("compute_seconds {seconds:.3}");
    Ok(())
}
