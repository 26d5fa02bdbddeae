//! The tiled z-buffer rasteriser: vertices to fixed-point sample coordinates, triangles
//! binned into screen tiles, tiles drawn in parallel and resolved to pixels.

use rayon::prelude::*;

use super::camera::Camera;
use super::shade::{lit, VertexColors, BACK, HIGHLIGHT};
use crate::shared_slice::SharedSlice;
use crate::vec3::{cross, sub};

/// The "no triangle" marker of a sample.
pub(crate) const NO_TRIANGLE: u32 = u32::MAX;
/// Fixed-point steps per sample: vertices are snapped to 1/256 of a sample.
const SUB: i64 = 256;
/// Pictures up to this many pixels get 2 × 2 samples per pixel, larger ones one.
const SUPERSAMPLED_PIXELS: u64 = 4096 * 4096;
/// Smallest tile side in pixels; larger pictures get larger tiles, so that there are at
/// most [`MAX_TILES`].
const TILE: u32 = 32;
const MAX_TILES: u64 = 4096;
/// Triangles per binning task.
const CHUNK: usize = 1 << 15;

/// What is drawn: the mesh and the colours chosen for it.
pub(crate) struct Scene<'a> {
    pub vertices: &'a [[f64; 3]],
    pub triangles: &'a [[u32; 3]],
    pub colors: &'a VertexColors,
    /// Per-triangle: drawn in [`HIGHLIGHT`].
    pub highlighted: Option<&'a [bool]>,
    pub background: [u8; 4],
}

/// A vertex on screen: fixed-point sample coordinates (`x = i32::MIN` for a vertex that is
/// not finite) and depth.
#[derive(Clone, Copy)]
struct Screen {
    x: i32,
    y: i32,
    z: f32,
}

impl Screen {
    fn is_finite(&self) -> bool {
        self.x != i32::MIN
    }
}

/// The sample grid: its size, the samples per pixel side and the tiling.
struct Grid {
    /// Samples per pixel side.
    ss: u32,
    width: u32,
    height: u32,
    /// Tile side in pixels.
    tile: u32,
    tiles_x: u32,
    tiles_y: u32,
}

impl Grid {
    fn new(width: u32, height: u32) -> Self {
        let ss = if width as u64 * height as u64 <= SUPERSAMPLED_PIXELS {
            2
        } else {
            1
        };
        let mut tile = TILE;
        while width.div_ceil(tile) as u64 * height.div_ceil(tile) as u64 > MAX_TILES {
            tile *= 2;
        }
        Self {
            ss,
            width,
            height,
            tile,
            tiles_x: width.div_ceil(tile),
            tiles_y: height.div_ceil(tile),
        }
    }

    fn tiles(&self) -> usize {
        (self.tiles_x * self.tiles_y) as usize
    }

    /// Samples per tile side.
    fn tile_samples(&self) -> i32 {
        (self.tile * self.ss) as i32
    }

    /// Sample rectangle of tile `t`: `[x0, x1) × [y0, y1)`.
    fn tile_rect(&self, t: usize) -> [i32; 4] {
        let (tx, ty) = (t as u32 % self.tiles_x, t as u32 / self.tiles_x);
        let ts = self.tile_samples();
        let (sw, sh) = (
            (self.width * self.ss) as i32,
            (self.height * self.ss) as i32,
        );
        [
            tx as i32 * ts,
            ((tx as i32 + 1) * ts).min(sw),
            ty as i32 * ts,
            ((ty as i32 + 1) * ts).min(sh),
        ]
    }
}

/// The smallest `n` with `n·SUB + SUB/2 ≥ v`: the first sample centre at or after `v`.
fn first_centre(v: i32) -> i32 {
    -(-(v as i64 - SUB / 2)).div_euclid(SUB) as i32
}

/// The largest `n` with `n·SUB + SUB/2 ≤ v`.
fn last_centre(v: i32) -> i32 {
    (v as i64 - SUB / 2).div_euclid(SUB) as i32
}

/// The samples whose centres a triangle's bounding box holds, `[x0, x1] × [y0, y1]`
/// (inclusive, clipped to the grid), or `None` when there is none or a vertex is not finite.
fn sample_box(s: &[Screen; 3], grid: &Grid) -> Option<[i32; 4]> {
    if !s.iter().all(Screen::is_finite) {
        return None;
    }
    let min = |f: fn(&Screen) -> i32| f(&s[0]).min(f(&s[1])).min(f(&s[2]));
    let max = |f: fn(&Screen) -> i32| f(&s[0]).max(f(&s[1])).max(f(&s[2]));
    let (sw, sh) = (
        (grid.width * grid.ss) as i32,
        (grid.height * grid.ss) as i32,
    );
    let x0 = first_centre(min(|v| v.x)).max(0);
    let x1 = last_centre(max(|v| v.x)).min(sw - 1);
    let y0 = first_centre(min(|v| v.y)).max(0);
    let y1 = last_centre(max(|v| v.y)).min(sh - 1);
    (x0 <= x1 && y0 <= y1).then_some([x0, x1, y0, y1])
}

/// Draws the scene through `camera`; returns its RGBA rows.
pub(crate) fn draw(scene: &Scene<'_>, camera: &Camera) -> Vec<u8> {
    let grid = Grid::new(camera.width, camera.height);
    let to_fixed = (grid.ss as i64 * SUB) as f64;
    let screen: Vec<Screen> = scene
        .vertices
        .par_iter()
        .map(|&v| {
            let [x, y, z] = camera.project(v);
            if [x, y, z].iter().all(|c| c.is_finite()) {
                Screen {
                    x: (x * to_fixed).round() as i32,
                    y: (y * to_fixed).round() as i32,
                    z: z as f32,
                }
            } else {
                Screen {
                    x: i32::MIN,
                    y: 0,
                    z: 0.0,
                }
            }
        })
        .collect();
    let corners = |t: &[u32; 3]| t.map(|i| screen[i as usize]);
    let (start, bins) = bin(scene.triangles, &grid, &corners);
    let tiles: Vec<Vec<u8>> = (0..grid.tiles())
        .into_par_iter()
        .map(|t| {
            let rect = grid.tile_rect(t);
            let list = &bins[start[t]..start[t + 1]];
            draw_tile(scene, camera, &grid, rect, list, &corners)
        })
        .collect();
    let (w, ss) = (grid.width as usize, grid.ss as i32);
    let mut rgba = vec![0u8; 4 * w * grid.height as usize];
    for (t, pixels) in tiles.iter().enumerate() {
        let [x0, x1, y0, y1] = grid.tile_rect(t).map(|c| (c / ss) as usize);
        let row = 4 * (x1 - x0);
        for (r, y) in (y0..y1).enumerate() {
            let at = 4 * (y * w + x0);
            rgba[at..at + row].copy_from_slice(&pixels[r * row..(r + 1) * row]);
        }
    }
    rgba
}

/// The triangles of every tile, in triangle order: tile `t`'s are
/// `bins[start[t]..start[t + 1]]`. A counting sort: triangles are counted per chunk and
/// tile, then written in parallel, each chunk to its own ranges.
fn bin(
    triangles: &[[u32; 3]],
    grid: &Grid,
    corners: &(impl Fn(&[u32; 3]) -> [Screen; 3] + Sync),
) -> (Vec<usize>, Vec<u32>) {
    let ts = grid.tile_samples();
    let tiles_of = |t: &[u32; 3]| {
        sample_box(&corners(t), grid).map(|[x0, x1, y0, y1]| [x0 / ts, x1 / ts, y0 / ts, y1 / ts])
    };
    let nt = grid.tiles();
    let tx = grid.tiles_x as usize;
    let each_tile = |r: [i32; 4], f: &mut dyn FnMut(usize)| {
        for y in r[2]..=r[3] {
            for x in r[0]..=r[1] {
                f(y as usize * tx + x as usize);
            }
        }
    };
    let counts: Vec<Vec<usize>> = triangles
        .par_chunks(CHUNK)
        .map(|chunk| {
            let mut c = vec![0usize; nt];
            for t in chunk {
                if let Some(r) = tiles_of(t) {
                    each_tile(r, &mut |i| c[i] += 1);
                }
            }
            c
        })
        .collect();
    // Offsets: tile by tile, chunk by chunk within a tile.
    let mut start = vec![0usize; nt + 1];
    let mut offsets: Vec<Vec<usize>> = vec![vec![0; nt]; counts.len()];
    let mut total = 0;
    for i in 0..nt {
        start[i] = total;
        for (c, counts) in counts.iter().enumerate() {
            offsets[c][i] = total;
            total += counts[i];
        }
    }
    start[nt] = total;
    drop(counts);
    let mut bins = vec![0u32; total];
    let shared = SharedSlice::new(&mut bins);
    triangles
        .par_chunks(CHUNK)
        .zip(offsets.par_iter_mut())
        .enumerate()
        .for_each(|(c, (chunk, next))| {
            for (k, t) in chunk.iter().enumerate() {
                if let Some(r) = tiles_of(t) {
                    let id = (c * CHUNK + k) as u32;
                    each_tile(r, &mut |i| {
                        // SAFETY: chunk `c` alone writes `offsets[c][i]..` up to its count
                        // for tile `i`, a range no other chunk or tile touches.
                        unsafe { shared.set(next[i], id) };
                        next[i] += 1;
                    });
                }
            }
        });
    (start, bins)
}

/// The edge function of `a → b` at `p`: positive on the inner side of a positively
/// oriented triangle, twice the area of `a b p`.
fn edge(a: (i64, i64), b: (i64, i64), p: (i64, i64)) -> i64 {
    (b.0 - a.0) * (p.1 - a.1) - (b.1 - a.1) * (p.0 - a.0)
}

/// Fixed-point position of a vertex.
fn pos(s: &Screen) -> (i64, i64) {
    (s.x as i64, s.y as i64)
}

/// Fixed-point position of sample centre `(x, y)`.
fn centre(x: i32, y: i32) -> (i64, i64) {
    (x as i64 * SUB + SUB / 2, y as i64 * SUB + SUB / 2)
}

/// Barycentric coordinates of `p` in the screen triangle (either orientation).
fn barycentric(s: &[Screen; 3], p: (i64, i64)) -> [f32; 3] {
    let [a, b, c] = s.map(|v| pos(&v));
    let area = edge(a, b, c) as f64;
    [edge(b, c, p), edge(c, a, p), edge(a, b, p)].map(|w| (w as f64 / area).clamp(0.0, 1.0) as f32)
}

/// Draws one tile: rasterises its triangles into the tile's own z-buffer, then shades and
/// averages the samples into pixels. Returns the tile's RGBA rows.
fn draw_tile(
    scene: &Scene<'_>,
    camera: &Camera,
    grid: &Grid,
    rect: [i32; 4],
    triangles: &[u32],
    corners: &impl Fn(&[u32; 3]) -> [Screen; 3],
) -> Vec<u8> {
    let [x0, x1, y0, y1] = rect;
    let tw = (x1 - x0) as usize;
    let mut depth = vec![f32::INFINITY; tw * (y1 - y0) as usize];
    let mut ids = vec![NO_TRIANGLE; depth.len()];
    for &t in triangles {
        let s = corners(&scene.triangles[t as usize]);
        rasterise(t, &s, grid, rect, &mut depth, &mut ids);
    }
    let ss = grid.ss as i32;
    let (pw, ph) = ((x1 - x0) / ss, (y1 - y0) / ss);
    let background = scene.background.map(|c| c as f32 / 255.0);
    let mut out = Vec::with_capacity(4 * (pw * ph) as usize);
    for py in 0..ph {
        for px in 0..pw {
            // Premultiplied sums over the pixel's samples.
            let mut sum = [0.0f32; 4];
            for sy in py * ss..(py + 1) * ss {
                for sx in px * ss..(px + 1) * ss {
                    let id = ids[sy as usize * tw + sx as usize];
                    let (rgb, a) = if id == NO_TRIANGLE {
                        ([background[0], background[1], background[2]], background[3])
                    } else {
                        let p = centre(x0 + sx, y0 + sy);
                        (shade(scene, camera, id, p, corners), 1.0)
                    };
                    for k in 0..3 {
                        sum[k] += rgb[k] * a;
                    }
                    sum[3] += a;
                }
            }
            let n = (ss * ss) as f32;
            let to_byte = |v: f32| (v * 255.0).round().clamp(0.0, 255.0) as u8;
            for k in 0..3 {
                out.push(if sum[3] > 0.0 {
                    to_byte(sum[k] / sum[3])
                } else {
                    0
                });
            }
            out.push(to_byte(sum[3] / n));
        }
    }
    out
}

/// Writes triangle `t` into the tile's z-buffer where it covers a sample centre and is
/// nearer than what is there (strictly: the first of equally deep triangles stays).
/// Top-left rule: a centre on an edge belongs to the triangle on whose side the edge is
/// "owned", so two triangles sharing an edge never both cover it.
fn rasterise(
    t: u32,
    s: &[Screen; 3],
    grid: &Grid,
    rect: [i32; 4],
    depth: &mut [f32],
    ids: &mut [u32],
) {
    let Some([bx0, bx1, by0, by1]) = sample_box(s, grid) else {
        return;
    };
    let (x0, x1) = (bx0.max(rect[0]), bx1.min(rect[1] - 1));
    let (y0, y1) = (by0.max(rect[2]), by1.min(rect[3] - 1));
    if x0 > x1 || y0 > y1 {
        return;
    }
    let (a, mut b, mut c) = (s[0], s[1], s[2]);
    let mut area = edge(pos(&a), pos(&b), pos(&c));
    if area == 0 {
        return;
    }
    if area < 0 {
        std::mem::swap(&mut b, &mut c);
        area = -area;
    }
    // Edges opposite a, b and c, with their fill-rule bias.
    let edges = [(b, c), (c, a), (a, b)].map(|(from, to)| {
        let (dx, dy) = (to.x as i64 - from.x as i64, to.y as i64 - from.y as i64);
        let owned = dy > 0 || (dy == 0 && dx < 0);
        (pos(&from), pos(&to), if owned { 0 } else { -1 }, -dy * SUB)
    });
    let inv_area = 1.0 / area as f32;
    let z = [a.z, b.z, c.z];
    let tw = (rect[1] - rect[0]) as usize;
    for y in y0..=y1 {
        let p = centre(x0, y);
        let mut w = edges.map(|(from, to, _, _)| edge(from, to, p));
        let row = (y - rect[2]) as usize * tw;
        for x in x0..=x1 {
            if (0..3).all(|k| w[k] + edges[k].2 >= 0) {
                let d = (w[0] as f32 * z[0] + w[1] as f32 * z[1] + w[2] as f32 * z[2]) * inv_area;
                let i = row + (x - rect[0]) as usize;
                if d < depth[i] {
                    depth[i] = d;
                    ids[i] = t;
                }
            }
            for k in 0..3 {
                w[k] += edges[k].3;
            }
        }
    }
}

/// The colour of triangle `t` at sample centre `p`, lit.
fn shade(
    scene: &Scene<'_>,
    camera: &Camera,
    t: u32,
    p: (i64, i64),
    corners: &impl Fn(&[u32; 3]) -> [Screen; 3],
) -> [f32; 3] {
    let tri = scene.triangles[t as usize];
    let [a, b, c] = tri.map(|i| scene.vertices[i as usize]);
    let normal = cross(sub(b, a), sub(c, a));
    let facing = crate::vec3::dot(normal, camera.forward) < 0.0;
    let base = if scene.highlighted.is_some_and(|h| h[t as usize]) {
        HIGHLIGHT
    } else if !facing {
        BACK
    } else {
        match scene.colors {
            VertexColors::Plain => super::FRONT,
            colors => colors.at(tri, barycentric(&corners(&tri), p)),
        }
    };
    lit(base, normal, camera.forward)
}
