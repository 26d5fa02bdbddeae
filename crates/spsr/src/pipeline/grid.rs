//! After stage 7 (issue 18): the implicit function sampled on a regular grid over the
//! bounding cube, and at arbitrary points.
//!
//! The values are `γ − χ`: the function minus the iso-value, with the sign turned so that it
//! is negative inside and positive outside (the convention of signed distances; χ itself is
//! about 1 inside and 0 outside). A grid of resolution `R` samples the centres of the `R³`
//! cells that divide the cube: `origin + spacing · (i, j, k)` with `spacing = cube / R` and
//! `origin` the centre of cell (0, 0, 0). Each value is χ evaluated on the octree
//! (ALGORITHM.md §8.1), not interpolated.

use rayon::prelude::*;

use super::{tree, Implicit};
use crate::evaluate::Evaluator;
use crate::{Error, Params, Result};

/// The coarsest grid: two samples along each axis.
pub const MIN_GRID_RES: u32 = 2;

/// The implicit function minus the iso-value on a regular grid over the bounding cube.
#[derive(Debug, Clone, PartialEq)]
pub struct Grid {
    /// Samples along each axis, `R`.
    pub res: usize,
    /// The centre of cell (0, 0, 0), in the input's units.
    pub origin: [f64; 3],
    /// The distance between neighbouring samples, in the input's units.
    pub spacing: f64,
    /// `R³` values, x slowest and z fastest: value `(i, j, k)` is at `(i · R + j) · R + k`
    /// (a C-ordered array of shape `(R, R, R)` indexed `[x, y, z]`). Negative inside.
    pub values: Vec<f32>,
}

/// The most bytes one allocation may hold.
const ADDRESSABLE: u64 = isize::MAX as u64;

/// Bytes a grid of resolution `res` holds (`u64::MAX` when more than that).
pub fn grid_bytes(res: u32) -> u64 {
    u64::from(res)
        .checked_pow(3)
        .and_then(|n| n.checked_mul(4))
        .unwrap_or(u64::MAX)
}

/// The largest resolution whose grid fits in `limit` bytes (0 when none does).
fn largest_res(limit: u64) -> u32 {
    // The cube root in floating point, then corrected by a step either way.
    let mut r = ((limit / 4) as f64).cbrt().min(f64::from(u32::MAX)) as u32;
    while r > 0 && grid_bytes(r) > limit {
        r -= 1;
    }
    while r < u32::MAX && grid_bytes(r + 1) <= limit {
        r += 1;
    }
    r
}

/// Refuses a grid resolution under [`MIN_GRID_RES`] or whose values would not fit the
/// memory limit (`params.max_memory`, else the memory available, and never more than one
/// allocation can hold).
pub fn check_res(res: u32, params: &Params) -> Result<()> {
    if res < MIN_GRID_RES {
        return Err(Error::invalid(
            "grid_res",
            res,
            format!("at least {MIN_GRID_RES} samples along each axis"),
        ));
    }
    // Without a limit, still no more than one allocation can hold.
    let limit = tree::memory_limit(params).map_or(ADDRESSABLE, |(l, _)| l.min(ADDRESSABLE));
    if grid_bytes(res) > limit {
        let most = largest_res(limit);
        return Err(Error::invalid(
            "grid_res",
            res,
            format!(
                "at most {most}: {res}³ float32 values need {}, more than the memory limit of {}",
                crate::gib(grid_bytes(res)),
                crate::gib(limit)
            ),
        ));
    }
    Ok(())
}

/// The solved implicit function of a reconstruction, kept for evaluation at any point
/// ([`crate::reconstruct_implicit`]).
#[derive(Debug)]
pub struct ImplicitFunction(pub(crate) Implicit);

impl ImplicitFunction {
    /// `γ − χ` at world-space points (negative inside); points outside the bounding cube
    /// take the value at the nearest point of the cube.
    pub fn values(&self, points: &[[f64; 3]]) -> Vec<f64> {
        self.0.values(points)
    }

    /// `γ − χ` and its gradient (per input unit, pointing outward) at world-space points.
    pub fn values_and_gradients(&self, points: &[[f64; 3]]) -> (Vec<f64>, Vec<[f64; 3]>) {
        self.0.values_and_gradients(points)
    }

    /// The function on an `res³` grid over the bounding cube ([`Grid`]); check `res` with
    /// [`check_res`] first.
    pub fn grid(&self, res: u32) -> Grid {
        self.0.grid(res)
    }

    /// The iso-value γ.
    pub fn iso_value(&self) -> f64 {
        self.0.iso
    }

    /// The bounding cube: its lowest corner and side, in the input's units.
    pub fn cube(&self) -> ([f64; 3], f64) {
        (self.0.frame.origin, self.0.frame.width)
    }
}

impl Implicit {
    /// `γ − χ` at world-space points (negative inside); points outside the bounding cube take
    /// the value at the nearest point of the cube.
    pub fn values(&self, points: &[[f64; 3]]) -> Vec<f64> {
        let eval = Evaluator::new(&self.tree, self.fem, &self.solution);
        points
            .par_iter()
            .map(|&p| self.iso - eval.value(self.frame.to_unit(p)))
            .collect()
    }

    /// `γ − χ` and its gradient (per input unit) at world-space points; the gradient points
    /// outward, along the surface's normal. Outside the cube, as [`Implicit::values`].
    pub fn values_and_gradients(&self, points: &[[f64; 3]]) -> (Vec<f64>, Vec<[f64; 3]>) {
        let eval = Evaluator::new(&self.tree, self.fem, &self.solution);
        let w = self.frame.width;
        points
            .par_iter()
            .map(|&p| {
                let (v, g) = eval.value_grad(self.frame.to_unit(p));
                (self.iso - v, g.map(|c| -c / w))
            })
            .unzip()
    }

    /// The function sampled on an `res³` grid over the bounding cube ([`Grid`]); check `res`
    /// with [`check_res`] first.
    pub fn grid(&self, res: u32) -> Grid {
        let r = res as usize;
        let spacing = self.frame.width / f64::from(res);
        let origin = self.frame.origin.map(|o| o + 0.5 * spacing);
        let eval = Evaluator::new(&self.tree, self.fem, &self.solution);
        let mut values = vec![0f32; r * r * r];
        // One x-slice per task; each writes its own part, so the grid does not depend on the
        // thread count.
        values
            .par_chunks_mut(r * r)
            .enumerate()
            .for_each(|(i, slice)| {
                for j in 0..r {
                    for k in 0..r {
                        let p = [
                            origin[0] + spacing * i as f64,
                            origin[1] + spacing * j as f64,
                            origin[2] + spacing * k as f64,
                        ];
                        slice[j * r + k] = (self.iso - eval.value(self.frame.to_unit(p))) as f32;
                    }
                }
            });
        Grid {
            res: r,
            origin,
            spacing,
            values,
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn huge_resolutions_are_refused_without_overflow() {
        assert_eq!(grid_bytes(10), 4000);
        assert_eq!(grid_bytes(u32::MAX), u64::MAX);
        assert_eq!(largest_res(4000), 10);
        assert_eq!(largest_res(3999), 9);
        assert_eq!(largest_res(3), 0);
        let limited = Params {
            max_memory: Some(1 << 30),
            ..Params::default()
        };
        // 2^22 cubed times 4 wraps to 0 in 64 bits.
        for res in [1u32 << 22, u32::MAX] {
            let e = check_res(res, &limited).unwrap_err().to_string();
            assert!(e.contains("at most 645"), "{e}");
        }
        // With no memory limit given, one allocation still bounds the grid.
        let unlimited = Params {
            max_memory: Some(u64::MAX),
            ..Params::default()
        };
        assert!(check_res(u32::MAX, &unlimited).is_err());
        assert!(check_res(1000, &unlimited).is_ok());
    }
}
