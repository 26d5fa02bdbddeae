//! Stage 9 (no spec section; the reconstruction's own check of its result): the figures that
//! tell a useless mesh from a good one, and the one warning, with advice, they may give.
//!
//! A reconstruction from good points is one closed piece per object, away from the bounding
//! cube (which is 10 % larger than the points' box). Three findings contradict that:
//!
//! - **surface cut by the cube**: where normals are flipped in places, χ's inside leaks out
//!   and the iso-surface runs on to the cube, which cuts it open (an open scan does this
//!   too, as its surface is continued to the cube); a closed object's surface stays well
//!   inside, as the cube is 10 % larger than the points' box;
//! - **normals against χ**: a consistently oriented cloud points out of the solved inside,
//!   `n · ∇χ < 0` at nearly every sample; where orientations contradict each other, χ
//!   follows one side and a large share of the samples disagree with it;
//! - **many pieces**: noise the splats do not average out is reconstructed as small closed
//!   bubbles around the surface.
//!
//! The thresholds were measured (ARCHITECTURE.md, "Diagnosis"): clean clouds stay far below
//! them, half-flipped normals and the 0.5 %-noise bunny far above.

use rayon::prelude::*;

use crate::density::Sample;
use crate::error::Warning;
use crate::evaluate::Evaluator;
use crate::pipeline::Frame;
use crate::vec3::dot;
use crate::Mesh;

/// At most this many samples are probed for their normal's agreement with ∇χ: the share is
/// a proportion, so a strided subset estimates it to about ±1 % at a fixed small cost.
const PROBES: usize = 16_384;

/// Vertices within this fraction of a finest cell of a face of the bounding cube lie on the
/// cube: extraction puts the vertices of a surface cut by the cube on its faces, while a
/// closed object's surface stays about 0.05 / 1.1 of the cube away (12 cells at depth 8).
pub const ON_CUBE_CELLS: f64 = 0.01;

/// Warn when more than this share of the probed samples have normals against ∇χ.
pub const CONTRADICTED_SHARE: f64 = 0.05;

/// Warn when the mesh has more pieces than this.
pub const MANY_PIECES: usize = 20;

/// A strided subset of the samples, with their normals, to compare with ∇χ once it is solved.
pub(crate) struct NormalProbe {
    positions: Vec<[f64; 3]>,
    normals: Vec<[f64; 3]>,
}

impl NormalProbe {
    /// Every k-th sample with a normal (normals that cancelled are skipped), at most
    /// [`PROBES`] of them.
    pub(crate) fn take(samples: &[Sample]) -> Self {
        let stride = samples.len().div_ceil(PROBES).max(1);
        let (positions, normals) = samples
            .iter()
            .step_by(stride)
            .filter(|s| s.normal != [0.0; 3])
            .map(|s| (s.pos, s.normal))
            .unzip();
        NormalProbe { positions, normals }
    }

    /// The share of the probed samples whose normal points into χ's inside (χ ≈ 1 inside, so
    /// an outward normal has `n · ∇χ < 0`); 0 when nothing was probed.
    pub(crate) fn contradicted(&self, eval: &Evaluator) -> f64 {
        if self.positions.is_empty() {
            return 0.0;
        }
        let against = self
            .positions
            .par_iter()
            .zip(&self.normals)
            .filter(|(p, n)| dot(eval.value_grad(**p).1, **n) > 0.0)
            .count();
        against as f64 / self.positions.len() as f64
    }
}

/// What the reconstruction found out about its own mesh (the figures behind the warnings
/// [`Warning::SurfaceOnCube`], [`Warning::ContradictoryNormals`] and
/// [`Warning::ManyPieces`]).
#[derive(Debug, Clone, Copy, PartialEq, Default)]
pub struct Diagnosis {
    /// Connected pieces of the mesh ([`crate::mesh::Closure::pieces`]).
    pub pieces: usize,
    /// Every edge is shared by exactly two triangles.
    pub closed: bool,
    /// Edges used by one triangle only (the rims of the holes).
    pub boundary_edges: usize,
    /// Vertices on the faces of the bounding cube (within [`ON_CUBE_CELLS`] of a finest
    /// cell): where the cube cuts the surface open.
    pub on_cube: usize,
    /// Share of the probed samples (0–1) whose normal points against the gradient of χ.
    pub contradicted_normals: f64,
    /// The depth of the run (the advice may suggest a lower one).
    pub depth: u32,
    /// The mesh was trimmed (so trimming is no advice).
    pub trimmed: bool,
}

impl Diagnosis {
    /// The figures of `mesh`, in the input's frame; `frame` is the bounding cube, `depth`
    /// the run's depth and `contradicted_normals` the probe's finding.
    pub(crate) fn of(mesh: &Mesh, frame: Frame, depth: u32, contradicted_normals: f64) -> Self {
        let closure = mesh.closure();
        Diagnosis {
            pieces: closure.pieces,
            closed: closure.closed,
            boundary_edges: closure.boundary_edges,
            on_cube: on_cube(mesh, frame, depth),
            contradicted_normals,
            depth,
            trimmed: false,
        }
    }

    /// The one warning these figures call for, the likeliest cause first: normals against χ
    /// and a surface cut by the cube both mean bad normals (which also make pieces), many
    /// pieces alone mean noise.
    pub fn warning(&self) -> Option<Warning> {
        if self.contradicted_normals > CONTRADICTED_SHARE {
            Some(Warning::ContradictoryNormals(*self))
        } else if self.on_cube > 0 {
            Some(Warning::SurfaceOnCube(*self))
        } else if self.pieces > MANY_PIECES {
            Some(Warning::ManyPieces(*self))
        } else {
            None
        }
    }
}

/// The number of `mesh`'s vertices on a face of the cube `frame` (within [`ON_CUBE_CELLS`]
/// of a finest cell at `depth`).
fn on_cube(mesh: &Mesh, frame: Frame, depth: u32) -> usize {
    let margin = ON_CUBE_CELLS / f64::from(1u32 << depth.min(30));
    mesh.vertices
        .par_iter()
        .filter(|&&v| {
            let u = frame.to_unit(v);
            u.iter().any(|&c| c < margin || c > 1.0 - margin)
        })
        .count()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn square(z: f64) -> Mesh {
        Mesh {
            vertices: vec![
                [-1.0, -1.0, z],
                [1.0, -1.0, z],
                [1.0, 1.0, z],
                [-1.0, 1.0, z],
            ],
            triangles: vec![[0, 1, 2], [0, 2, 3]],
            ..Mesh::default()
        }
    }

    #[test]
    fn vertices_on_the_faces_of_the_cube_are_counted() {
        let frame = Frame {
            origin: [-1.0; 3],
            width: 2.0,
        };
        // The square spans the cube at x, y = ±1: its four corners lie on the faces.
        assert_eq!(on_cube(&square(0.5), frame, 8), 4);
        let inside = Frame {
            origin: [-1.1; 3],
            width: 2.2,
        };
        assert_eq!(on_cube(&square(0.5), inside, 8), 0);
    }

    #[test]
    fn the_likeliest_cause_is_the_one_warning() {
        let clean = Diagnosis {
            pieces: 1,
            closed: true,
            depth: 8,
            ..Diagnosis::default()
        };
        assert_eq!(clean.warning(), None);
        let noisy = Diagnosis {
            pieces: 178,
            ..clean
        };
        assert!(matches!(noisy.warning(), Some(Warning::ManyPieces(_))));
        let leaking = Diagnosis {
            on_cube: 30,
            ..noisy
        };
        assert!(matches!(leaking.warning(), Some(Warning::SurfaceOnCube(_))));
        let flipped = Diagnosis {
            contradicted_normals: 0.4,
            ..leaking
        };
        assert!(matches!(
            flipped.warning(),
            Some(Warning::ContradictoryNormals(_))
        ));
    }
}
