//! Scores a mesh against a ground truth, for the benchmark scripts:
//! `mesh_distance <MESH> <GT.ply | sphere:cx,cy,cz,r> [samples]` prints one JSON line with the
//! mean and max distances in both directions (area-uniform samples, fixed seed).

use spsr::metrics::{sample_surface, MeshDistance};

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    if args.len() < 3 {
        return Err("usage: mesh_distance <MESH> <GT.ply | sphere:cx,cy,cz,r> [samples]".into());
    }
    let mesh = spsr::io::read_mesh(args[1].as_ref())?;
    let n: usize = args.get(3).map_or(Ok(200_000), |s| s.parse())?;
    let samples = sample_surface(&mesh, n, 1);
    let stats = |d: &[f64]| {
        let mean = d.iter().sum::<f64>() / d.len().max(1) as f64;
        let max = d.iter().copied().fold(0.0, f64::max);
        (mean, max)
    };
    let (to_gt, from_gt) = if let Some(spec) = args[2].strip_prefix("sphere:") {
        let v: Vec<f64> = spec.split(',').map(str::parse).collect::<Result<_, _>>()?;
        let d: Vec<f64> = samples
            .iter()
            .map(|p| {
                let r =
                    ((p[0] - v[0]).powi(2) + (p[1] - v[1]).powi(2) + (p[2] - v[2]).powi(2)).sqrt();
                (r - v[3]).abs()
            })
            .collect();
        (stats(&d), (f64::NAN, f64::NAN))
    } else {
        let gt = spsr::io::read_mesh(args[2].as_ref())?;
        let to = MeshDistance::new(&gt).distances(&samples);
        let from = MeshDistance::new(&mesh).distances(&sample_surface(&gt, n, 2));
        (stats(&to), stats(&from))
    };
    let t = mesh.topology();
    println!(
        "{{\"vertices\": {}, \"faces\": {}, \"closed\": {}, \"manifold\": {}, \"mesh_to_gt_mean\": {:e}, \"mesh_to_gt_max\": {:e}, \"gt_to_mesh_mean\": {:e}, \"gt_to_mesh_max\": {:e}}}",
        t.vertices,
        t.faces,
        t.closed,
        t.edge_manifold && t.vertex_manifold,
        to_gt.0,
        to_gt.1,
        if from_gt.0.is_nan() { 0.0 } else { from_gt.0 },
        if from_gt.1.is_nan() { 0.0 } else { from_gt.1 },
    );
    Ok(())
}
