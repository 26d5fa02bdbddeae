//! Area-uniform surface samples on meshes and spheres, from a counter-based generator so that
//! sample `i` depends only on the seed and `i`.

use rayon::prelude::*;

use super::triangle_normal;
use crate::vec3::{cross, norm, sub};
use crate::Mesh;

/// SplitMix64 finaliser: a well-mixed 64-bit hash.
#[inline]
fn mix64(mut z: u64) -> u64 {
    z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
    z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
    z ^ (z >> 31)
}

/// Four uniform numbers in `[0, 1)` for sample `i` of the stream `seed` (counter-based, so
/// samples can be drawn in parallel and in any order).
#[inline]
fn uniforms(seed: u64, i: u64) -> [f64; 4] {
    let base = mix64(seed ^ 0x9e37_79b9_7f4a_7c15).wrapping_add(i.wrapping_mul(4));
    std::array::from_fn(|k| {
        let r = mix64(
            base.wrapping_add(k as u64)
                .wrapping_mul(0x9e37_79b9_7f4a_7c15),
        );
        (r >> 11) as f64 / (1u64 << 53) as f64
    })
}

/// Walker's alias table over `weights` (Vose's construction): `pick(u, v)` returns index `i`
/// with probability `weights[i] / Σ weights` in O(1), with two memory reads.
struct AliasTable {
    prob: Vec<f64>,
    alias: Vec<u32>,
}

impl AliasTable {
    fn new(weights: &[f64], total: f64) -> Self {
        let n = weights.len();
        let scale = n as f64 / total;
        let mut prob: Vec<f64> = weights.iter().map(|w| w * scale).collect();
        let mut alias: Vec<u32> = (0..n as u32).collect();
        let (mut small, mut large): (Vec<u32>, Vec<u32>) =
            (0..n as u32).partition(|&i| prob[i as usize] < 1.0);
        while let (Some(&s), Some(&l)) = (small.last(), large.last()) {
            small.pop();
            alias[s as usize] = l;
            let rest = prob[l as usize] - (1.0 - prob[s as usize]);
            prob[l as usize] = rest;
            if rest < 1.0 {
                large.pop();
                small.push(l);
            }
        }
        // Leftovers are 1 up to rounding; a zero-weight leftover keeps its own index and is
        // caught by the caller's fallback.
        for i in large.into_iter().chain(small) {
            if prob[i as usize] > 0.0 {
                prob[i as usize] = 1.0;
            }
        }
        AliasTable { prob, alias }
    }

    #[inline]
    fn pick(&self, u: f64, v: f64) -> usize {
        let n = self.prob.len();
        let i = ((u * n as f64) as usize).min(n - 1);
        if v < self.prob[i] {
            i
        } else {
            self.alias[i] as usize
        }
    }
}

/// A point sampled on a surface, with the surface's unit normal there.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct SurfaceSample {
    /// Position.
    pub point: [f64; 3],
    /// Unit normal (of the sampled triangle, or radial on a sphere).
    pub normal: [f64; 3],
}

/// `n` points sampled area-uniformly on the mesh's triangles, with the normal of the triangle
/// each lies on. Deterministic: the same mesh, `n` and seed give the same samples, whatever the
/// number of threads. Empty when the mesh has no area (or `n == 0`); triangles with
/// out-of-range indices are ignored.
pub fn sample_surface_with_normals(mesh: &Mesh, n: usize, seed: u64) -> Vec<SurfaceSample> {
    let nv = mesh.vertices.len();
    let areas: Vec<f64> = mesh
        .triangles
        .par_iter()
        .map(|t| {
            if t.iter().any(|&i| i as usize >= nv) {
                return 0.0;
            }
            let [a, b, c] = t.map(|i| mesh.vertices[i as usize]);
            let a2 = 0.5 * norm(cross(sub(b, a), sub(c, a)));
            if a2.is_finite() {
                a2
            } else {
                0.0
            }
        })
        .collect();
    let total: f64 = areas.iter().sum();
    if !(total > 0.0 && total.is_finite()) || n == 0 {
        return Vec::new();
    }
    let table = AliasTable::new(&areas, total);
    (0..n as u64)
        .into_par_iter()
        .map(|i| {
            let [r, q, mut u, mut v] = uniforms(seed, i);
            let mut t = table.pick(r, q);
            if areas[t] <= 0.0 {
                // Rounding in the table's construction; never in practice. Take the first
                // triangle with area instead.
                t = areas.iter().position(|&a| a > 0.0).unwrap_or(0);
            }
            let [a, b, c] = mesh.triangles[t].map(|i| mesh.vertices[i as usize]);
            if u + v > 1.0 {
                u = 1.0 - u;
                v = 1.0 - v;
            }
            SurfaceSample {
                point: std::array::from_fn(|k| a[k] + u * (b[k] - a[k]) + v * (c[k] - a[k])),
                normal: triangle_normal(a, b, c),
            }
        })
        .collect()
}

/// `n` points sampled area-uniformly on the mesh's triangles with a fixed seed
/// (deterministic: the same mesh and seed give the same points, whatever the thread count).
pub fn sample_surface(mesh: &Mesh, n: usize, seed: u64) -> Vec<[f64; 3]> {
    sample_surface_with_normals(mesh, n, seed)
        .into_iter()
        .map(|s| s.point)
        .collect()
}

/// `n` points sampled area-uniformly on a sphere (Archimedes: uniform height and angle), with
/// radial normals. Deterministic like [`sample_surface_with_normals`].
pub fn sample_sphere(center: [f64; 3], radius: f64, n: usize, seed: u64) -> Vec<SurfaceSample> {
    (0..n as u64)
        .into_par_iter()
        .map(|i| {
            let [u, v, _, _] = uniforms(seed, i);
            let z = 2.0 * u - 1.0;
            let s = (1.0 - z * z).max(0.0).sqrt();
            let phi = 2.0 * std::f64::consts::PI * v;
            let normal = [s * phi.cos(), s * phi.sin(), z];
            SurfaceSample {
                point: std::array::from_fn(|k| center[k] + radius * normal[k]),
                normal,
            }
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vec3::dot;

    #[test]
    fn samples_are_area_uniform_and_deterministic() {
        // Two triangles, areas 1 and 3: about a quarter of the samples land on the first.
        let mesh = Mesh {
            vertices: vec![
                [0.0, 0.0, 0.0],
                [1.0, 0.0, 0.0],
                [0.0, 2.0, 0.0],
                [10.0, 0.0, 0.0],
                [13.0, 0.0, 0.0],
                [10.0, 2.0, 0.0],
            ],
            triangles: vec![[0, 1, 2], [3, 4, 5]],
            ..Default::default()
        };
        let s = sample_surface_with_normals(&mesh, 40_000, 5);
        let first = s.iter().filter(|s| s.point[0] < 5.0).count() as f64 / 40_000.0;
        assert!((first - 0.25).abs() < 0.01, "{first}");
        assert!(s
            .iter()
            .all(|s| s.normal == [0.0, 0.0, 1.0] && s.point[2] == 0.0));
        assert_eq!(s, sample_surface_with_normals(&mesh, 40_000, 5));
        assert_ne!(s, sample_surface_with_normals(&mesh, 40_000, 6));
        // A prefix of a longer run is the shorter run.
        assert_eq!(s[..100], sample_surface_with_normals(&mesh, 100, 5)[..]);
    }

    #[test]
    fn sphere_samples_are_uniform() {
        let s = sample_sphere([1.0, 2.0, 3.0], 2.0, 50_000, 3);
        let mut mean = [0.0; 3];
        for x in &s {
            let d = sub(x.point, [1.0, 2.0, 3.0]);
            assert!((norm(d) - 2.0).abs() < 1e-12);
            assert!((dot(d, x.normal) - 2.0).abs() < 1e-12);
            for k in 0..3 {
                mean[k] += x.normal[k] / s.len() as f64;
            }
        }
        assert!(norm(mean) < 0.02, "{mean:?}");
        // Upper hemisphere above z = 0.5 holds a quarter of the area (Archimedes).
        let cap = s.iter().filter(|x| x.normal[2] > 0.5).count() as f64 / s.len() as f64;
        assert!((cap - 0.25).abs() < 0.01, "{cap}");
    }
}
