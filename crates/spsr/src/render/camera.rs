//! The orthographic camera of each view, fitted to the mesh.

use rayon::prelude::*;

use super::View;
use crate::vec3::{cross, dot, norm, scale};

/// Fraction of the picture's width and height left empty on each side.
const MARGIN: f64 = 0.05;

/// An orthographic camera: a world point `p` lands at pixel coordinates
/// `(width/2 + scale·(p·right − cx), height/2 − scale·(p·up − cy))` (pixel `(i, j)` covers
/// `[i, i+1) × [j, j+1)`), at depth `p·forward` (larger is farther).
#[derive(Debug, Clone, PartialEq)]
pub(crate) struct Camera {
    pub right: [f64; 3],
    pub up: [f64; 3],
    /// The viewing direction.
    pub forward: [f64; 3],
    /// `p·right` and `p·up` of the picture's centre.
    pub centre: [f64; 2],
    /// Pixels per unit of length.
    pub scale: f64,
    pub width: u32,
    pub height: u32,
}

/// The viewing direction and the world direction shown upwards, of a single view.
fn axes(view: View) -> ([f64; 3], [f64; 3]) {
    match view {
        View::Front => ([0.0, 0.0, -1.0], [0.0, 1.0, 0.0]),
        View::Side => ([-1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
        View::Top => ([0.0, -1.0, 0.0], [0.0, 0.0, -1.0]),
        // Y projected onto the picture plane.
        View::Iso | View::All => {
            let s = 1.0 / 3f64.sqrt();
            let up = [-1.0, 2.0, -1.0];
            ([-s, -s, -s], scale(up, 1.0 / norm(up)))
        }
    }
}

impl Camera {
    /// The camera of `view` (a single view, not [`View::All`]) that fits the finite
    /// vertices into a `width × height` picture; `None` when no vertex is finite.
    pub fn fit(vertices: &[[f64; 3]], view: View, width: u32, height: u32) -> Option<Camera> {
        let (forward, up) = axes(view);
        let right = cross(forward, up);
        let empty = || {
            [
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
            ]
        };
        let [x0, x1, y0, y1] = vertices
            .par_iter()
            .filter(|v| v.iter().all(|c| c.is_finite()))
            .fold(empty, |b, &v| {
                let (x, y) = (dot(v, right), dot(v, up));
                [b[0].min(x), b[1].max(x), b[2].min(y), b[3].max(y)]
            })
            .reduce(empty, |a, b| {
                [
                    a[0].min(b[0]),
                    a[1].max(b[1]),
                    a[2].min(b[2]),
                    a[3].max(b[3]),
                ]
            });
        if x0 > x1 {
            return None;
        }
        let usable = |pixels: u32| pixels as f64 * (1.0 - 2.0 * MARGIN);
        let fit = |pixels: u32, extent: f64| {
            if extent > 0.0 {
                usable(pixels) / extent
            } else {
                f64::INFINITY
            }
        };
        let pixels_per_unit = fit(width, x1 - x0).min(fit(height, y1 - y0));
        Some(Camera {
            right,
            up,
            forward,
            centre: [0.5 * (x0 + x1), 0.5 * (y0 + y1)],
            // A single point: any scale draws nothing.
            scale: if pixels_per_unit.is_finite() {
                pixels_per_unit
            } else {
                1.0
            },
            width,
            height,
        })
    }

    /// Pixel coordinates and depth of a world point.
    pub fn project(&self, p: [f64; 3]) -> [f64; 3] {
        [
            0.5 * self.width as f64 + self.scale * (dot(p, self.right) - self.centre[0]),
            0.5 * self.height as f64 - self.scale * (dot(p, self.up) - self.centre[1]),
            dot(p, self.forward),
        ]
    }
}
