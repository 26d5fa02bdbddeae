//! The evaluation of a mesh against a ground truth: Chamfer and Hausdorff distances,
//! F-scores, normal consistency and topology, and their JSON form.

use rayon::prelude::*;

use super::{sample_sphere, sample_surface_with_normals, triangle_normal};
use super::{MeshDistance, SurfaceSample};
use crate::mesh::Topology;
use crate::morton::BoxKeys;
use crate::vec3::{dot, norm, sub, V3};
use crate::{Error, Mesh, Result};

/// The ground truth a mesh is scored against.
#[derive(Debug, Clone, PartialEq)]
pub enum Reference {
    /// A triangle mesh (closed or open).
    Mesh(Mesh),
    /// An analytic sphere.
    Sphere {
        /// Centre.
        center: [f64; 3],
        /// Radius (positive).
        radius: f64,
    },
}

/// Options of [`evaluate`].
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct EvalOptions {
    /// Samples drawn on each surface (at least 1).
    pub samples: usize,
    /// Seed of the sample generator; the mesh uses `seed`, the reference `seed + 1`.
    pub seed: u64,
}

impl Default for EvalOptions {
    /// One million samples per surface, seed 1.
    fn default() -> Self {
        EvalOptions {
            samples: 1_000_000,
            seed: 1,
        }
    }
}

/// Precision, recall and F-score at one distance threshold.
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct FScore {
    /// The threshold τ (absolute units).
    pub threshold: f64,
    /// Fraction of mesh samples within τ of the reference.
    pub precision: f64,
    /// Fraction of reference samples within τ of the mesh.
    pub recall: f64,
    /// `2PR / (P + R)`, 0 when both are 0.
    pub fscore: f64,
}

/// Statistics of one direction (samples of one surface measured against the other).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Direction {
    /// Mean distance.
    pub mean: f64,
    /// Largest distance.
    pub max: f64,
    /// Mean of `|n_sample · n_other|` at the closest point.
    pub normal_consistency: f64,
    /// Fraction of samples within the 0.5 % threshold.
    pub within_0_5: f64,
    /// Fraction of samples within the 1 % threshold.
    pub within_1: f64,
}

/// Scores of a mesh against a reference, as computed by [`evaluate`].
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Evaluation {
    /// Symmetric Chamfer distance: mean of the two directions' mean distances.
    pub chamfer: f64,
    /// [`Self::chamfer`] divided by the reference's bounding-box diagonal.
    pub chamfer_rel: f64,
    /// Hausdorff distance (over the samples): the larger of the two directions' maxima.
    pub hausdorff: f64,
    /// [`Self::hausdorff`] divided by the reference's bounding-box diagonal.
    pub hausdorff_rel: f64,
    /// Mesh samples measured against the reference (accuracy; the meaningful direction
    /// for an open ground truth is usually the other one).
    pub mesh_to_reference: Direction,
    /// Reference samples measured against the mesh (completeness).
    pub reference_to_mesh: Direction,
    /// F-score at 0.5 % of the reference's bounding-box diagonal.
    pub fscore_0_5: FScore,
    /// F-score at 1 % of the reference's bounding-box diagonal.
    pub fscore_1: FScore,
    /// Mean of the two directions' normal consistencies (1 = normals parallel everywhere).
    pub normal_consistency: f64,
    /// Bounding-box diagonal of the reference (of its triangles' vertices; `2√3·r` for a
    /// sphere).
    pub diagonal: f64,
    /// Samples drawn on each surface.
    pub samples: usize,
    /// Surface area of the mesh.
    pub area: f64,
    /// Surface area of the reference.
    pub reference_area: f64,
    /// Topology of the mesh.
    pub topology: Topology,
}

fn json_number(x: f64) -> String {
    if !x.is_finite() {
        "null".into()
    } else if x == 0.0 || (1e-4..1e15).contains(&x.abs()) {
        format!("{x}")
    } else {
        format!("{x:e}")
    }
}

impl Evaluation {
    /// The evaluation as one line of JSON (an object; numbers in shortest round-trip form,
    /// booleans as booleans). Keys: `chamfer`, `chamfer_rel`, `hausdorff`, `hausdorff_rel`,
    /// `mesh_to_reference_mean`/`_max`, `reference_to_mesh_mean`/`_max`, `fscore_0_5`,
    /// `precision_0_5`, `recall_0_5`, `tau_0_5` (and the same with `_1`),
    /// `normal_consistency` (and per direction), `diagonal`, `samples`, `area`,
    /// `reference_area`, then the mesh's `vertices`, `faces`, `closed`, `edge_manifold`,
    /// `vertex_manifold`, `oriented`, `components`, `euler`, `boundary_edges`,
    /// `non_manifold_edges`, `non_manifold_vertices`.
    pub fn to_json(&self) -> String {
        let t = &self.topology;
        let nums = [
            ("chamfer", self.chamfer),
            ("chamfer_rel", self.chamfer_rel),
            ("hausdorff", self.hausdorff),
            ("hausdorff_rel", self.hausdorff_rel),
            ("mesh_to_reference_mean", self.mesh_to_reference.mean),
            ("mesh_to_reference_max", self.mesh_to_reference.max),
            ("reference_to_mesh_mean", self.reference_to_mesh.mean),
            ("reference_to_mesh_max", self.reference_to_mesh.max),
            ("fscore_0_5", self.fscore_0_5.fscore),
            ("precision_0_5", self.fscore_0_5.precision),
            ("recall_0_5", self.fscore_0_5.recall),
            ("tau_0_5", self.fscore_0_5.threshold),
            ("fscore_1", self.fscore_1.fscore),
            ("precision_1", self.fscore_1.precision),
            ("recall_1", self.fscore_1.recall),
            ("tau_1", self.fscore_1.threshold),
            ("normal_consistency", self.normal_consistency),
            (
                "normal_consistency_mesh_to_reference",
                self.mesh_to_reference.normal_consistency,
            ),
            (
                "normal_consistency_reference_to_mesh",
                self.reference_to_mesh.normal_consistency,
            ),
            ("diagonal", self.diagonal),
            ("area", self.area),
            ("reference_area", self.reference_area),
        ];
        let ints = [
            ("samples", self.samples as i64),
            ("vertices", t.vertices as i64),
            ("faces", t.faces as i64),
            ("components", t.components as i64),
            ("euler", t.euler),
            ("boundary_edges", t.boundary_edges as i64),
            ("non_manifold_edges", t.non_manifold_edges as i64),
            ("non_manifold_vertices", t.non_manifold_vertices as i64),
        ];
        let bools = [
            ("closed", t.closed),
            ("edge_manifold", t.edge_manifold),
            ("vertex_manifold", t.vertex_manifold),
            ("oriented", t.oriented),
        ];
        let fields: Vec<String> = nums
            .iter()
            .map(|(k, v)| format!("\"{k}\": {}", json_number(*v)))
            .chain(ints.iter().map(|(k, v)| format!("\"{k}\": {v}")))
            .chain(bools.iter().map(|(k, v)| format!("\"{k}\": {v}")))
            .collect();
        format!("{{{}}}", fields.join(", "))
    }
}

/// Checks that `mesh` can be sampled and measured: indices in range, finite coordinates on
/// every triangle, positive finite area. `what` names the mesh in the message.
fn check_mesh(mesh: &Mesh, what: &str) -> Result<()> {
    let nv = mesh.vertices.len();
    if mesh.triangles.is_empty() {
        return Err(Error::Degenerate(format!("the {what} has no triangles")));
    }
    if let Some((f, _)) = mesh
        .triangles
        .iter()
        .enumerate()
        .find(|(_, t)| t.iter().any(|&i| i as usize >= nv))
    {
        return Err(Error::Degenerate(format!(
            "triangle {f} of the {what} refers to a vertex that does not exist ({nv} vertices)"
        )));
    }
    let bad = mesh.triangles.par_iter().position_first(|t| {
        t.iter()
            .any(|&i| mesh.vertices[i as usize].iter().any(|x| !x.is_finite()))
    });
    if let Some(f) = bad {
        return Err(Error::Degenerate(format!(
            "triangle {f} of the {what} has a vertex with non-finite coordinates"
        )));
    }
    let area = mesh.area();
    if !(area > 0.0 && area.is_finite()) {
        return Err(Error::Degenerate(format!(
            "the {what} has no area (all {} triangles are degenerate)",
            mesh.triangles.len()
        )));
    }
    Ok(())
}

/// Bounding-box diagonal of the vertices used by the triangles.
fn diagonal(mesh: &Mesh) -> f64 {
    let mut lo = [f64::INFINITY; 3];
    let mut hi = [f64::NEG_INFINITY; 3];
    for t in &mesh.triangles {
        for &v in t {
            let x = mesh.vertices[v as usize];
            for k in 0..3 {
                lo[k] = lo[k].min(x[k]);
                hi[k] = hi[k].max(x[k]);
            }
        }
    }
    norm(sub(hi, lo))
}

/// Sorts samples along a Morton (Z-order) curve, so consecutive queries visit the same parts
/// of the hierarchy (far fewer cache misses). The order is fully determined by the samples.
fn sort_spatially(samples: &mut [SurfaceSample]) {
    if samples.is_empty() {
        return;
    }
    let keys = BoxKeys::around(samples.iter().map(|s| s.point));
    let mut keyed: Vec<(u64, SurfaceSample)> = samples
        .par_iter()
        .map(|s| (keys.key(s.point), *s))
        .collect();
    // Stable, so equal keys keep their (deterministic) sample order.
    keyed.par_sort_by_key(|e| e.0);
    samples
        .par_iter_mut()
        .zip(keyed.par_iter())
        .for_each(|(s, e)| *s = e.1);
}

/// Distance and `|n · n_other|` for each sample, in order.
type Measured = Vec<(f64, f64)>;

fn measure_against_mesh(samples: &[SurfaceSample], target: &MeshDistance) -> Measured {
    let mesh = target.mesh();
    samples
        .par_iter()
        .map(|s| match target.closest(s.point) {
            Some(c) => {
                let [a, b, cc] =
                    mesh.triangles[c.triangle as usize].map(|i| mesh.vertices[i as usize]);
                (c.distance, dot(s.normal, triangle_normal(a, b, cc)).abs())
            }
            None => (f64::INFINITY, 0.0),
        })
        .collect()
}

fn measure_against_sphere(samples: &[SurfaceSample], center: V3, radius: f64) -> Measured {
    samples
        .par_iter()
        .map(|s| {
            let d = sub(s.point, center);
            let r = norm(d);
            // At the centre every point of the sphere is closest; no radial direction exists.
            let cos = if r > 0.0 {
                (dot(s.normal, d) / r).abs().min(1.0)
            } else {
                0.0
            };
            ((r - radius).abs(), cos)
        })
        .collect()
}

/// Sequential (hence thread-count independent) reduction of one direction.
fn summarize(m: &Measured, tau: [f64; 2]) -> Direction {
    let n = m.len().max(1) as f64;
    let (mut sum, mut max, mut cos) = (0.0, 0.0f64, 0.0);
    let mut within = [0usize; 2];
    for &(d, c) in m {
        sum += d;
        max = max.max(d);
        cos += c;
        for k in 0..2 {
            within[k] += (d <= tau[k]) as usize;
        }
    }
    Direction {
        mean: sum / n,
        max,
        normal_consistency: cos / n,
        within_0_5: within[0] as f64 / n,
        within_1: within[1] as f64 / n,
    }
}

fn fscore(threshold: f64, precision: f64, recall: f64) -> FScore {
    let fscore = if precision + recall > 0.0 {
        2.0 * precision * recall / (precision + recall)
    } else {
        0.0
    };
    FScore {
        threshold,
        precision,
        recall,
        fscore,
    }
}

/// Scores `mesh` against `reference` with `opts.samples` area-uniform samples on each surface
/// and exact point-to-triangle distances (point-to-sphere for an analytic sphere).
///
/// The F-score thresholds are 0.5 % and 1 % of the reference's bounding-box diagonal; a
/// sample is "within" τ when its distance is at most τ. Normal consistency compares each
/// sample's normal with the normal of the other surface at the closest point (the closest
/// triangle's face normal, or the radial direction of a sphere), ignoring orientation. The
/// Hausdorff distance is the largest sampled distance, so it is a lower bound of the true one.
/// The result is deterministic and independent of the number of threads.
///
/// # Errors
/// [`Error::InvalidParameter`] if `opts.samples` is 0 or the sphere's centre or radius is
/// not finite or the radius not positive; [`Error::Degenerate`] if either mesh has no
/// triangles, no area, an index out of range or non-finite coordinates (the message says
/// whether it is the mesh or the reference).
pub fn evaluate(mesh: &Mesh, reference: &Reference, opts: &EvalOptions) -> Result<Evaluation> {
    if opts.samples == 0 {
        return Err(Error::invalid("samples", 0, "at least 1"));
    }
    if let Reference::Sphere { center, radius } = reference {
        if !(center.iter().all(|x| x.is_finite()) && *radius > 0.0 && radius.is_finite()) {
            return Err(Error::invalid(
                "reference_sphere",
                format!("centre {center:?}, radius {radius}"),
                "a finite centre and a positive radius",
            ));
        }
    }
    check_mesh(mesh, "mesh")?;
    if let Reference::Mesh(r) = reference {
        check_mesh(r, "reference mesh")?;
    }
    let n = opts.samples;
    let seed_ref = opts.seed.wrapping_add(1);
    let (diag, reference_area) = match reference {
        Reference::Mesh(r) => (diagonal(r), r.area()),
        Reference::Sphere { radius, .. } => (
            2.0 * 3f64.sqrt() * radius,
            4.0 * std::f64::consts::PI * radius * radius,
        ),
    };
    let tau = [0.005 * diag, 0.01 * diag];
    let (to_ref, from_ref) = match reference {
        Reference::Mesh(r) => {
            let ((mesh_tree, ref_tree), (mesh_samples, ref_samples)) = rayon::join(
                || rayon::join(|| MeshDistance::new(mesh), || MeshDistance::new(r)),
                || {
                    rayon::join(
                        || sample_surface_with_normals(mesh, n, opts.seed),
                        || sample_surface_with_normals(r, n, seed_ref),
                    )
                },
            );
            let (mut mesh_samples, mut ref_samples) = (mesh_samples, ref_samples);
            rayon::join(
                || sort_spatially(&mut mesh_samples),
                || sort_spatially(&mut ref_samples),
            );
            (
                measure_against_mesh(&mesh_samples, &ref_tree),
                measure_against_mesh(&ref_samples, &mesh_tree),
            )
        }
        Reference::Sphere { center, radius } => {
            let (mesh_tree, (mesh_samples, ref_samples)) = rayon::join(
                || MeshDistance::new(mesh),
                || {
                    rayon::join(
                        || sample_surface_with_normals(mesh, n, opts.seed),
                        || sample_sphere(*center, *radius, n, seed_ref),
                    )
                },
            );
            let mut ref_samples = ref_samples;
            sort_spatially(&mut ref_samples);
            (
                measure_against_sphere(&mesh_samples, *center, *radius),
                measure_against_mesh(&ref_samples, &mesh_tree),
            )
        }
    };
    let a = summarize(&to_ref, tau);
    let b = summarize(&from_ref, tau);
    let chamfer = 0.5 * (a.mean + b.mean);
    let hausdorff = a.max.max(b.max);
    Ok(Evaluation {
        chamfer,
        chamfer_rel: chamfer / diag,
        hausdorff,
        hausdorff_rel: hausdorff / diag,
        mesh_to_reference: a,
        reference_to_mesh: b,
        fscore_0_5: fscore(tau[0], a.within_0_5, b.within_0_5),
        fscore_1: fscore(tau[1], a.within_1, b.within_1),
        normal_consistency: 0.5 * (a.normal_consistency + b.normal_consistency),
        diagonal: diag,
        samples: n,
        area: mesh.area(),
        reference_area,
        topology: mesh.topology(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_numbers() {
        assert_eq!(json_number(0.0), "0");
        assert_eq!(json_number(0.25), "0.25");
        assert_eq!(json_number(1.5e-7), "1.5e-7");
        assert_eq!(json_number(f64::NAN), "null");
    }
}
