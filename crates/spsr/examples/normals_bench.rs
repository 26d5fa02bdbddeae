//! Measures normal estimation and orientation on a point file whose normals serve as the
//! reference, for `bench/normals/run.py`:
//!
//! ```text
//! normals_bench <POINTS.ply> <MODE> [--gt <GT.ply | sphere:cx,cy,cz,r | box:x0,y0,z0,x1,y1,z1>]
//!               [--depth D] [--samples N] [--neighbours K] [--threads T]
//! ```
//!
//! MODE is `mst`, `global`, `viewpoint:x,y,z`, or `true` (the file's own normals, to measure
//! the reconstruction they give). POINTS may also be `synth:shell:N:GAP` or
//! `synth:plate:N:T` (generated, exact normals), or an ASCII PLY without normals together
//! with `--reference-viewpoint x,y,z` (the estimated normals turned towards that point are
//! the reference). `--write-input PATH` writes the points and reference normals as binary PLY
//! for other tools. The file's normals are ignored for estimation. Prints one
//! JSON line: orientation agreement with the file's normals, mean angle, stage times, peak
//! resident memory of the process, and with `--gt` the distances from a depth-D
//! reconstruction to the ground truth (mean over N area-uniform samples in each direction).

use std::time::Instant;

use spsr::metrics::{evaluate, EvalOptions, Reference};
use spsr::normals::{compare, estimate, orient, NormalParams, Orientation};
use spsr::{Mesh, Params, PointCloud};

/// The test suite's synthetic clouds (the same generator and box sampling).
#[path = "../tests/common/clouds.rs"]
mod clouds;

use clouds::{boxed, Rng};

fn parse3(s: &str) -> Result<Vec<f64>, Box<dyn std::error::Error>> {
    Ok(s.split(',').map(str::parse).collect::<Result<_, _>>()?)
}

fn box_mesh(lo: [f64; 3], hi: [f64; 3]) -> Mesh {
    let vertices = (0..8)
        .map(|c| std::array::from_fn(|a| if c >> a & 1 == 1 { hi[a] } else { lo[a] }))
        .collect();
    // Two counter-clockwise (seen from outside) triangles per face.
    let quads = [
        [0, 2, 3, 1],
        [4, 5, 7, 6],
        [0, 1, 5, 4],
        [2, 6, 7, 3],
        [0, 4, 6, 2],
        [1, 3, 7, 5],
    ];
    let triangles = quads
        .iter()
        .flat_map(|q: &[u32; 4]| [[q[0], q[1], q[2]], [q[0], q[2], q[3]]])
        .collect();
    Mesh {
        vertices,
        triangles,
        density: None,
        normals: None,
        attributes: Vec::new(),
    }
}

/// Synthetic inputs with exact outward normals: `shell:N:GAP` (a hollow ball: spheres of
/// radius 1 and 1 − GAP, the inner one's normals pointing to the centre) and `plate:N:T`
/// (a 1 × 1 × T box).
fn synthetic(spec: &str) -> Result<PointCloud, Box<dyn std::error::Error>> {
    let parts: Vec<&str> = spec.split(':').collect();
    let n: usize = parts.get(1).ok_or("N missing")?.parse()?;
    let t: f64 = parts.get(2).ok_or("size missing")?.parse()?;
    let seed = 0x9e3779b97f4a7c15;
    match parts[0] {
        "shell" => shell(n, t, seed),
        "plate" => Ok(boxed(n, [0.5, 0.5, 0.5 * t], seed)),
        _ => Err(format!("unknown synthetic input {spec}").into()),
    }
}

/// `n` points on a hollow ball, spheres of radius 1 and `1 − gap` in proportion to their
/// areas, with normals pointing out of the solid wall.
fn shell(n: usize, gap: f64, seed: u64) -> Result<PointCloud, Box<dyn std::error::Error>> {
    let mut rng = Rng(seed);
    let r2 = (1.0 - gap) * (1.0 - gap);
    let mut pos = Vec::with_capacity(n);
    let mut nor = Vec::with_capacity(n);
    while pos.len() < n {
        let u = rng.unit();
        if rng.next() * (1.0 + r2) < 1.0 {
            pos.push(u);
            nor.push(u);
        } else {
            pos.push(u.map(|c| c * (1.0 - gap)));
            nor.push(u.map(|c| -c));
        }
    }
    Ok(PointCloud::new(pos, nor)?)
}

/// Positions from an ASCII PLY whose vertices have no normals (the raw Stanford range scans):
/// the first three numbers of each vertex line.
fn read_ascii_positions(path: &str) -> Result<Vec<[f64; 3]>, Box<dyn std::error::Error>> {
    let text = std::fs::read_to_string(path)?;
    let mut lines = text.lines();
    let mut count = None;
    for line in lines.by_ref() {
        if let Some(n) = line.strip_prefix("element vertex ") {
            count = Some(n.trim().parse::<usize>()?);
        }
        if line.trim() == "end_header" {
            break;
        }
    }
    let count = count.ok_or("no vertex element")?;
    lines
        .take(count)
        .map(|l| {
            let v: Vec<f64> = l
                .split_whitespace()
                .take(3)
                .map(str::parse)
                .collect::<Result<_, _>>()?;
            Ok([v[0], v[1], v[2]])
        })
        .collect()
}

/// Writes positions and reference normals as binary little-endian PLY (float32), the shared
/// data's format, so that other tools can read the same input.
fn write_points(path: &str, cloud: &PointCloud) -> Result<(), Box<dyn std::error::Error>> {
    let mut out = format!(
        "ply\nformat binary_little_endian 1.0\nelement vertex {}\n\
         property float x\nproperty float y\nproperty float z\n\
         property float nx\nproperty float ny\nproperty float nz\nend_header\n",
        cloud.len()
    )
    .into_bytes();
    for (p, n) in cloud.positions.iter().zip(&cloud.normals) {
        for v in p.iter().chain(n) {
            out.extend_from_slice(&(*v as f32).to_le_bytes());
        }
    }
    std::fs::write(path, out)?;
    Ok(())
}

fn peak_rss_mib() -> f64 {
    spsr_peak_rss().map_or(f64::NAN, |b| b as f64 / (1u64 << 20) as f64)
}

fn spsr_peak_rss() -> Option<u64> {
    let status = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = status.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb * 1024)
}

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        return Err(
            "usage: normals_bench <POINTS.ply> <mst|global|viewpoint:x,y,z|true> \
                    [--gt G] [--depth D] [--samples N] [--neighbours K] [--threads T]"
                .into(),
        );
    }
    let mut gt = None;
    let mut depth = 8;
    let mut samples = 200_000;
    let mut neighbours = None;
    let mut threads = 0;
    let mut reference_viewpoint = None;
    let mut write_input = None;
    let mut it = args[3..].iter();
    while let Some(a) = it.next() {
        let v = it.next().ok_or(format!("{a} needs a value"))?;
        match a.as_str() {
            "--gt" => gt = Some(v.clone()),
            "--depth" => depth = v.parse()?,
            "--samples" => samples = v.parse()?,
            "--neighbours" => neighbours = Some(v.parse()?),
            "--threads" => threads = v.parse()?,
            "--reference-viewpoint" => reference_viewpoint = Some(v.clone()),
            "--write-input" => write_input = Some(v.clone()),
            _ => return Err(format!("unknown option {a}").into()),
        }
    }
    rayon::ThreadPoolBuilder::new()
        .num_threads(threads)
        .build_global()?;
    let mode = args[2].as_str();
    let t = Instant::now();
    let cloud = match args[1].strip_prefix("synth:") {
        Some(spec) => synthetic(spec)?,
        None => match spsr::io::read_points(args[1].as_ref()) {
            Err(spsr::Error::MissingNormals { .. }) => {
                // No reference normals: the estimated normals oriented towards the sensor
                // (--reference-viewpoint) serve as the reference.
                let pos = read_ascii_positions(&args[1])?;
                let v = parse3(
                    reference_viewpoint
                        .as_deref()
                        .ok_or("the points have no normals: give --reference-viewpoint x,y,z")?,
                )?;
                let mut n = estimate(&pos, &NormalParams::default())?.normals;
                orient(&pos, &mut n, &Orientation::Viewpoint([v[0], v[1], v[2]]))?;
                PointCloud::new(pos, n)?
            }
            other => other?,
        },
    };
    let t_read = t.elapsed().as_secs_f64();
    let reference = cloud.normals.clone();
    if let Some(path) = write_input {
        write_points(&path, &cloud)?;
    }
    let mut out = vec![
        format!("\"input\": \"{}\"", args[1]),
        format!("\"points\": {}", cloud.len()),
        format!("\"mode\": \"{mode}\""),
        format!("\"read_s\": {t_read:.3}"),
    ];
    let normals = if mode == "true" {
        reference.clone()
    } else {
        let how = if let Some(k) = mode.strip_prefix("mst") {
            match k.strip_prefix(':') {
                Some(k) => Orientation::Mst {
                    neighbours: k.parse()?,
                },
                None => Orientation::mst(),
            }
        } else if let Some(d) = mode.strip_prefix("global") {
            match d.strip_prefix(':') {
                Some(d) => Orientation::Global {
                    neighbours: 10,
                    depth: Some(d.parse()?),
                    rounds: 4,
                },
                None => Orientation::global(),
            }
        } else if let Some(v) = mode.strip_prefix("viewpoint:") {
            let v = parse3(v)?;
            Orientation::Viewpoint([v[0], v[1], v[2]])
        } else {
            return Err(format!("unknown mode {mode}").into());
        };
        let t = Instant::now();
        let est = estimate(
            &cloud.positions,
            &NormalParams {
                neighbours,
                ..NormalParams::default()
            },
        )?;
        let t_est = t.elapsed().as_secs_f64();
        let mut normals = est.normals;
        let t = Instant::now();
        let stats = orient(&cloud.positions, &mut normals, &how)?;
        let t_orient = t.elapsed().as_secs_f64();
        let c = compare(&normals, &reference)?;
        out.extend([
            format!("\"neighbours\": {}", est.neighbours),
            format!("\"noisy\": {}", est.noisy),
            format!("\"degenerate\": {}", est.degenerate),
            format!("\"components\": {}", stats.components),
            format!("\"corrections\": {:?}", stats.corrections),
            format!("\"estimate_s\": {t_est:.3}"),
            format!("\"orient_s\": {t_orient:.3}"),
            format!("\"normals_s\": {:.3}", t_est + t_orient),
            format!("\"peak_rss_mib\": {:.1}", peak_rss_mib()),
            format!(
                "\"oriented_pct\": {:.4}",
                100.0 * (1.0 - c.flipped_fraction)
            ),
            format!("\"mean_angle_deg\": {:.3}", c.mean_angle_deg),
            format!("\"median_angle_deg\": {:.3}", c.median_angle_deg),
        ]);
        normals
    };
    if let Some(g) = gt {
        let reference = if let Some(s) = g.strip_prefix("sphere:") {
            let v = parse3(s)?;
            Reference::Sphere {
                center: [v[0], v[1], v[2]],
                radius: v[3],
            }
        } else if let Some(s) = g.strip_prefix("box:") {
            let v = parse3(s)?;
            Reference::Mesh(box_mesh([v[0], v[1], v[2]], [v[3], v[4], v[5]]))
        } else {
            Reference::Mesh(spsr::io::read_mesh(g.as_ref())?)
        };
        let t = Instant::now();
        let rec = spsr::reconstruct(
            &PointCloud::new(cloud.positions.clone(), normals)?,
            &Params {
                depth,
                ..Params::default()
            },
        )?;
        let t_rec = t.elapsed().as_secs_f64();
        let e = evaluate(&rec.mesh, &reference, &EvalOptions { samples, seed: 1 })?;
        let topo = rec.mesh.topology();
        out.extend([
            format!("\"depth\": {depth}"),
            format!("\"reconstruct_s\": {t_rec:.3}"),
            format!("\"mesh_to_gt\": {:e}", e.mesh_to_reference.mean),
            format!("\"gt_to_mesh\": {:e}", e.reference_to_mesh.mean),
            format!("\"chamfer\": {:e}", e.chamfer),
            format!("\"components_mesh\": {}", topo.components),
        ]);
    }
    println!("{{{}}}", out.join(", "));
    Ok(())
}
