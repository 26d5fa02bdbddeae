//! Stage 2 (ALGORITHM.md §3.3, §3.5): merge the points of each finest cell into samples and
//! estimate the sampling density, which gives every sample its depth and area weight.

use rayon::prelude::*;

use super::prepare::{Carried, UnitPoint};
use crate::attributes::Attribute;
use crate::density::{merge_samples_grouped, Density, DepthAndArea, Sample};
use crate::Params;

/// The output of [`sample`].
#[derive(Debug)]
pub struct Sampled {
    /// The samples, in Morton order of their cells.
    pub samples: Vec<Sample>,
    /// Each sample's attribute values (the weighted mean over its points), `channels` per
    /// sample.
    pub values: Vec<f64>,
    /// Name and type of each attribute (empty columns), in channel order.
    pub attribute_types: Vec<Attribute>,
    /// The density estimator (kept for the per-vertex density of the mesh).
    pub density: Density,
    /// Each sample's estimated depth and area weight.
    pub depths: Vec<DepthAndArea>,
}

impl Sampled {
    /// Each sample's weight in the screening term, the iso-value and the attributes' field:
    /// its weight times the share its screening keeps ([`DepthAndArea::screen`]).
    pub fn screening_weights(&self) -> Vec<f64> {
        (self.samples.iter().zip(&self.depths))
            .map(|(s, q)| s.weight * q.screen)
            .collect()
    }
}

/// The density estimator of the samples at the parameters' kernel depth and samples per
/// node (also rebuilt by the slabs' coarse phase from the samples they keep).
pub fn estimator(samples: &[Sample], params: &Params) -> Density {
    Density::build(samples, params.kernel_depth(), params.samples_per_node)
}

/// Merges the prepared points into samples and estimates their density (stage 2). The points
/// are released before the density is built.
pub fn sample(points: Vec<UnitPoint>, carried: Carried, params: &Params) -> Sampled {
    let channels = carried.channels();
    let (samples, sample_of) = merge_samples_grouped(&points, params.depth, channels > 0);
    let values = sample_values(&points, &carried, &samples, &sample_of);
    drop(sample_of);
    let attribute_types = carried.types;
    drop(carried.values);
    drop(points);
    let density = estimator(&samples, params);
    let depths = samples.par_iter().map(|s| density.query(s.pos)).collect();
    Sampled {
        samples,
        values,
        attribute_types,
        density,
        depths,
    }
}

/// Each sample's attributes: the weighted mean over its points.
fn sample_values(
    points: &[UnitPoint],
    carried: &Carried,
    samples: &[Sample],
    sample_of: &[u32],
) -> Vec<f64> {
    let channels = carried.channels();
    let point_values = &carried.values;
    let mut values = vec![0.0f64; samples.len() * channels];
    for (p, &s) in sample_of.iter().enumerate() {
        if s == u32::MAX {
            continue;
        }
        let w = points[p].2 / samples[s as usize].weight;
        let row = &mut values[s as usize * channels..(s as usize + 1) * channels];
        for (o, v) in row
            .iter_mut()
            .zip(&point_values[p * channels..(p + 1) * channels])
        {
            *o += w * v;
        }
    }
    values
}
