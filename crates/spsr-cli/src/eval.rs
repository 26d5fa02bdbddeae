//! `spsr eval`: score a mesh against a ground-truth mesh or an analytic sphere.

use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use clap::Args;

use crate::args::ThreadsArg;
use crate::{exit, start_threads, usage, Failure};

pub(crate) const EVAL_LONG_ABOUT: &str = "\
Score a mesh against a ground truth: a mesh (--reference) or an analytic sphere \
(--reference-sphere cx,cy,cz,r).

Both surfaces get the same number of area-uniform samples (fixed seed, so the numbers are \
reproducible and independent of the thread count); every sample is measured against the other \
surface with exact point-to-triangle distances. Reported: the symmetric Chamfer distance (mean \
of the two directions' mean distances) and the Hausdorff distance (largest sampled distance), \
both also relative to the reference's bounding-box diagonal, each direction's mean and maximum, \
the F-score at 0.5 % and 1 % of that diagonal, the normal consistency (mean |n · n'| at the \
closest points, both directions), and the mesh's topology (vertices, faces, closed, edge- and \
vertex-manifold, components, Euler characteristic, consistent orientation).

Input meshes, recognised by their first bytes or else by extension: PLY (any encoding; vertex x, \
y, z and face vertex_indices), OBJ, STL (binary or ASCII; corners at the same position merged into \
one vertex, so the topology can be checked), OFF, or glTF binary (.glb).";

/// Arguments of `spsr eval`.
#[derive(Debug, Args)]
pub struct EvalArgs {
    /// Mesh to score: PLY, OBJ, STL, OFF or GLB.
    #[arg(value_name = "MESH")]
    pub mesh: PathBuf,

    /// Ground-truth mesh (PLY, OBJ, STL, OFF or GLB). Exactly one of --reference and
    /// --reference-sphere is needed.
    #[arg(long, value_name = "GT_MESH")]
    pub reference: Option<PathBuf>,

    /// Analytic sphere as ground truth: centre and radius, comma-separated.
    #[arg(long, value_name = "CX,CY,CZ,R", allow_hyphen_values = true)]
    pub reference_sphere: Option<String>,

    /// Samples drawn on each surface, at least 1.
    #[arg(
        long,
        value_name = "N",
        default_value_t = spsr::metrics::EvalOptions::default().samples as i64,
        allow_negative_numbers = true
    )]
    pub samples: i64,

    /// Print one JSON object (on the last line of stdout) instead of the table [default: off]
    #[arg(long)]
    pub json: bool,

    #[command(flatten)]
    pub threads: ThreadsArg,
}

/// Parses `cx,cy,cz,r` (spaces allowed around the commas): finite numbers, positive radius.
fn parse_sphere(spec: &str) -> Result<([f64; 3], f64), Failure> {
    let bad = |why: &str| {
        usage(format!(
            "invalid --reference-sphere '{spec}': {why} (expected cx,cy,cz,r, e.g. 0,0,0,1)"
        ))
    };
    let parts: Vec<&str> = spec.split(',').map(str::trim).collect();
    if parts.len() != 4 {
        return Err(bad(&format!("{} values instead of 4", parts.len())));
    }
    let mut v = [0.0; 4];
    for (x, p) in v.iter_mut().zip(&parts) {
        *x = p
            .parse::<f64>()
            .ok()
            .filter(|x| x.is_finite())
            .ok_or_else(|| bad(&format!("'{p}' is not a finite number")))?;
    }
    if v[3] <= 0.0 {
        return Err(bad("the radius must be positive"));
    }
    Ok(([v[0], v[1], v[2]], v[3]))
}

/// Reads a mesh for `spsr eval`, refusing one without area; errors name the file.
fn read_eval_mesh(path: &Path) -> Result<spsr::Mesh, Failure> {
    let mesh = spsr::io::read_mesh(path).map_err(|e| Failure::from_spsr(e, path))?;
    let area = mesh.area();
    if mesh.triangles.is_empty() || !(area > 0.0 && area.is_finite()) {
        let what = if mesh.triangles.is_empty() {
            "no faces"
        } else {
            "no surface area (non-finite or degenerate faces)"
        };
        return Err(Failure {
            code: exit::DATA,
            error: anyhow::anyhow!("{}: the mesh has {what}", path.display()),
        });
    }
    Ok(mesh)
}

/// Runs `spsr eval`: reads the mesh and the reference, scores, prints a table or JSON.
pub fn run_eval(args: &EvalArgs) -> Result<(), Failure> {
    // Usage checks first, before any reading.
    let samples = usize::try_from(args.samples)
        .ok()
        .filter(|&n| n >= 1)
        .ok_or_else(|| {
            usage(format!(
                "invalid parameter --samples: must be at least 1, got {}",
                args.samples
            ))
        })?;
    let sphere = match (&args.reference, &args.reference_sphere) {
        (None, None) => {
            return Err(usage(
                "no reference: give --reference GT_MESH or --reference-sphere cx,cy,cz,r".into(),
            ))
        }
        (Some(_), Some(_)) => {
            return Err(usage(
                "--reference and --reference-sphere cannot be used together; give one".into(),
            ))
        }
        (None, Some(spec)) => Some(parse_sphere(spec)?),
        (Some(_), None) => None,
    };
    start_threads(args.threads.threads)?;
    let start = Instant::now();
    let mesh = read_eval_mesh(&args.mesh)?;
    let (reference, reference_name) = match (sphere, &args.reference) {
        (Some((center, radius)), _) => (
            spsr::metrics::Reference::Sphere { center, radius },
            format!(
                "sphere, centre ({}, {}, {}), radius {radius}",
                center[0], center[1], center[2]
            ),
        ),
        (None, Some(path)) => (
            spsr::metrics::Reference::Mesh(read_eval_mesh(path)?),
            path.display().to_string(),
        ),
        (None, None) => unreachable!("checked above"),
    };
    let opts = spsr::metrics::EvalOptions {
        samples,
        ..Default::default()
    };
    let e = spsr::metrics::evaluate(&mesh, &reference, &opts)
        .map_err(|e| Failure::from_spsr(e, &args.mesh))?;
    if args.json {
        println!("{}", e.to_json());
    } else {
        print_evaluation(&args.mesh, &reference_name, &e, start.elapsed());
    }
    Ok(())
}

fn print_evaluation(
    mesh: &Path,
    reference: &str,
    e: &spsr::metrics::Evaluation,
    elapsed: Duration,
) {
    let t = &e.topology;
    let yes = |b: bool| if b { "yes" } else { "no" };
    let pct = |x: f64| format!("{:.3} %", 100.0 * x);
    let rows: Vec<(String, String)> = vec![
        ("mesh".into(), mesh.display().to_string()),
        ("reference".into(), reference.to_string()),
        ("samples per surface".into(), e.samples.to_string()),
        (
            "reference bbox diagonal".into(),
            format!("{:.6e}", e.diagonal),
        ),
        (
            "chamfer".into(),
            format!("{:.6e}  ({} of diagonal)", e.chamfer, pct(e.chamfer_rel)),
        ),
        (
            "hausdorff".into(),
            format!(
                "{:.6e}  ({} of diagonal)",
                e.hausdorff,
                pct(e.hausdorff_rel)
            ),
        ),
        (
            "mesh -> reference".into(),
            format!(
                "mean {:.6e}, max {:.6e}",
                e.mesh_to_reference.mean, e.mesh_to_reference.max
            ),
        ),
        (
            "reference -> mesh".into(),
            format!(
                "mean {:.6e}, max {:.6e}",
                e.reference_to_mesh.mean, e.reference_to_mesh.max
            ),
        ),
        (
            "f-score @ 0.5 %".into(),
            format!(
                "{:.4}  (precision {:.4}, recall {:.4}, tau {:.4e})",
                e.fscore_0_5.fscore,
                e.fscore_0_5.precision,
                e.fscore_0_5.recall,
                e.fscore_0_5.threshold
            ),
        ),
        (
            "f-score @ 1 %".into(),
            format!(
                "{:.4}  (precision {:.4}, recall {:.4}, tau {:.4e})",
                e.fscore_1.fscore, e.fscore_1.precision, e.fscore_1.recall, e.fscore_1.threshold
            ),
        ),
        (
            "normal consistency".into(),
            format!(
                "{:.6}  (mesh -> reference {:.6}, reference -> mesh {:.6})",
                e.normal_consistency,
                e.mesh_to_reference.normal_consistency,
                e.reference_to_mesh.normal_consistency
            ),
        ),
        ("vertices".into(), t.vertices.to_string()),
        ("faces".into(), t.faces.to_string()),
        (
            "closed".into(),
            format!("{}  ({} boundary edges)", yes(t.closed), t.boundary_edges),
        ),
        (
            "edge-manifold".into(),
            format!(
                "{}  ({} non-manifold edges)",
                yes(t.edge_manifold),
                t.non_manifold_edges
            ),
        ),
        (
            "vertex-manifold".into(),
            format!(
                "{}  ({} non-manifold vertices)",
                yes(t.vertex_manifold),
                t.non_manifold_vertices
            ),
        ),
        ("oriented".into(), yes(t.oriented).into()),
        ("components".into(), t.components.to_string()),
        ("euler characteristic".into(), t.euler.to_string()),
        ("time".into(), format!("{:.2} s", elapsed.as_secs_f64())),
    ];
    let mut out = std::io::stdout().lock();
    for (k, v) in rows {
        let _ = writeln!(out, "{k:<24} {v}");
    }
}
