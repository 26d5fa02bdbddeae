//! Stage 7 (ALGORITHM.md §1.5): the iso-value γ, the weighted mean of χ at the samples.

use rayon::prelude::*;

use super::system::SamplePoints;
use crate::evaluate::Evaluator;

/// γ = Σ w_s χ(p_s) / Σ w_s (stage 7).
pub fn iso_value(eval: &Evaluator, samples: &SamplePoints) -> f64 {
    let values: Vec<f64> = samples
        .positions
        .par_iter()
        .map(|p| eval.value(*p))
        .collect();
    let weights = &samples.weights;
    values.iter().zip(weights).map(|(v, w)| v * w).sum::<f64>() / weights.iter().sum::<f64>()
}
