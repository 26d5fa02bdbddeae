//! Density trimming: removing the surface the reconstruction invented where there were no
//! samples (ALGORITHM.md §10, the reference's `SurfaceTrimmer`).
//!
//! Screened Poisson reconstruction always returns a closed surface, so a scan of an open
//! scene (a room, a terrain, a statue on a plinth, the Stanford bunny's open bottom) comes
//! back closed over the parts the scanner never saw. The per-vertex density written with
//! `--density` ([`Mesh::density`], ALGORITHM.md §9.5: the estimated sampling depth, a log
//! scale where one unit is 4× more samples per area) is high where samples were and falls
//! away from them. [`trim`] keeps the part of the mesh where the density is at least a
//! threshold `V`, in three steps:
//!
//! 1. **Cut along the iso-line `density = V`.** Every edge whose end densities lie on both
//!    sides of `V` gets a new vertex at the linearly interpolated crossing; the two triangles
//!    of the edge share it, so no crack opens. Every per-vertex value (density, normals,
//!    each attribute in its own type) is interpolated there. A cut triangle leaves a triangle
//!    or a quadrilateral (split along its shorter diagonal) on each side. The boundary of the
//!    kept surface therefore follows the iso-line instead of the jagged edges that dropping
//!    whole triangles leaves. A vertex whose density is exactly `V` lies on the line and
//!    belongs to both sides; a triangle all of whose vertices are at `V` is discarded, as in
//!    the reference (it keeps values strictly above the threshold).
//! 2. **Islands and holes.** The kept and the discarded triangles are split into
//!    edge-connected components; a kept and a discarded component are neighbours when they
//!    share an edge. As in the reference, the smallest component that has a neighbour is
//!    merged into its neighbours (it changes side) while it is small: a kept component
//!    smaller than [`TrimParams::min_island_area`] of the total area is dropped, a discarded
//!    one smaller than [`TrimParams::hole_area`] is restored, which closes small holes inside
//!    kept surface. The reference uses one ratio (`--aRatio`, default 0.001) for both; spsr
//!    has one for each, both defaulting to that value. Kept components with no discarded
//!    neighbour at all (separate pieces of the mesh) are dropped when smaller than
//!    `min_island_area` too (the reference does so only with `--removeIslands`).
//! 3. **Clean-up.** Only the kept triangles remain; vertices no triangle uses are removed.
//!    Original vertices keep their order, the new cut vertices follow.
//!
//! Everything runs in a fixed order, so the result does not depend on the thread count.
//!
//! ## The automatic threshold
//!
//! [`Threshold::Auto`] cuts at `V = median − max(1, 4 × MAD)` of the area-weighted vertex
//! densities (MAD: median absolute deviation from the median): it removes the surface whose
//! samples per area are fewer than a quarter of the typical surface's, or, for unevenly
//! sampled scans, further below the typical density than four MADs. [`auto_threshold`]
//! gives the reasoning and the measurements behind it.

use std::cmp::Reverse;
use std::collections::BinaryHeap;

use rayon::slice::ParallelSliceMut;
use rustc_hash::FxHashMap;

use crate::attributes::{Attribute, AttributeData};
use crate::error::Error;
use crate::mesh::Mesh;
use crate::vec3::{cross, norm, norm2, sub};
use crate::Result;

/// Which density level to cut at.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Threshold {
    /// Keep the surface whose density is at least this value (the reference's `--trim`).
    Value(f32),
    /// Derive the value from the mesh's density distribution ([`auto_threshold`]).
    Auto,
}

/// Parameters of [`trim`].
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrimParams {
    /// The density level to cut at. Default [`Threshold::Auto`].
    pub threshold: Threshold,
    /// Kept components smaller than this fraction of the mesh's total area are removed.
    /// Default 0.001, the reference's `--aRatio`. 0 keeps every island.
    pub min_island_area: f64,
    /// Discarded regions inside kept surface smaller than this fraction of the mesh's total
    /// area are restored (the hole is closed again). Default 0.001, the reference's
    /// `--aRatio`. 0 restores nothing.
    pub hole_area: f64,
}

impl Default for TrimParams {
    fn default() -> Self {
        Self {
            threshold: Threshold::Auto,
            min_island_area: 0.001,
            hole_area: 0.001,
        }
    }
}

impl TrimParams {
    /// Checks the parameters: a finite threshold value, area fractions in `[0, 1)`.
    ///
    /// # Errors
    /// [`Error::InvalidParameter`] naming the field (`threshold`, `min_island_area`,
    /// `hole_area`).
    pub fn validate(&self) -> Result<()> {
        if let Threshold::Value(v) = self.threshold {
            if !v.is_finite() {
                return Err(Error::invalid(
                    "threshold",
                    v,
                    "a finite density value, or auto",
                ));
            }
        }
        for (field, v) in [
            ("min_island_area", self.min_island_area),
            ("hole_area", self.hole_area),
        ] {
            if !(v.is_finite() && (0.0..1.0).contains(&v)) {
                return Err(Error::invalid(
                    field,
                    v,
                    "a fraction of the total area in [0, 1), such as 0.001",
                ));
            }
        }
        Ok(())
    }
}

/// How [`auto_threshold`] arrived at its value.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AutoThreshold {
    /// The threshold chosen.
    pub threshold: f32,
    /// Area-weighted median of the vertex densities.
    pub median: f64,
    /// Area-weighted median absolute deviation from the median.
    pub mad: f64,
    /// Fraction of the mesh's area whose density is below the threshold (before cutting).
    pub area_below: f64,
}

/// What [`trim`] did.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct TrimStats {
    /// The density level cut at.
    pub threshold: f32,
    /// The automatic rule's details, when [`Threshold::Auto`] was asked for.
    pub auto: Option<AutoThreshold>,
    /// Total area of the input mesh.
    pub total_area: f64,
    /// Area of the output mesh.
    pub kept_area: f64,
    /// Vertices added on edges crossing the iso-line.
    pub cut_vertices: usize,
    /// Kept components removed because they were smaller than `min_island_area`.
    pub islands_removed: usize,
    /// Discarded regions restored because they were smaller than `hole_area`.
    pub holes_filled: usize,
    /// Triangles of the input mesh.
    pub triangles_in: usize,
    /// Triangles of the output mesh.
    pub triangles_out: usize,
}

fn invalid_mesh(message: String) -> Error {
    Error::InvalidMesh(message)
}

/// The error for a mesh without area to trim.
pub(crate) fn no_area() -> Error {
    invalid_mesh("the mesh has no surface area (degenerate or non-finite triangles)".into())
}

/// The error for a threshold that removes the whole mesh, whose densities span `range`.
pub(crate) fn keeps_nothing(threshold: f32, range: (f32, f32)) -> Error {
    let (lo, hi) = range;
    Error::invalid(
        "threshold",
        format!("{threshold}, which removes the whole mesh"),
        format!(
            "a value that keeps some of the mesh (its densities range from {lo} to {hi}), or auto"
        ),
    )
}

/// Checks the mesh can be trimmed and returns its densities.
fn check_mesh(mesh: &Mesh) -> Result<&[f32]> {
    let density = mesh.density.as_deref().ok_or(Error::MissingDensity)?;
    let nv = mesh.vertices.len();
    if density.len() != nv {
        return Err(invalid_mesh(format!(
            "the mesh has {} density values for {nv} vertices",
            density.len()
        )));
    }
    if let Some(n) = &mesh.normals {
        if n.len() != nv {
            return Err(invalid_mesh(format!(
                "the mesh has {} normals for {nv} vertices",
                n.len()
            )));
        }
    }
    for a in &mesh.attributes {
        if a.len() != nv {
            return Err(invalid_mesh(format!(
                "attribute '{}' has {} values for {nv} vertices",
                a.name,
                a.len()
            )));
        }
    }
    if mesh.triangles.is_empty() {
        return Err(invalid_mesh("the mesh has no triangles".into()));
    }
    // Each triangle adds at most two cut vertices (each shared edge's counts for both).
    if nv as u64 + 2 * mesh.triangles.len() as u64 > u64::from(u32::MAX) {
        return Err(invalid_mesh(format!(
            "the mesh is too large to trim: {nv} vertices and {} triangles could need more \
             than 2^32 vertices after cutting",
            mesh.triangles.len()
        )));
    }
    if let Some((f, t)) = mesh
        .triangles
        .iter()
        .enumerate()
        .find(|(_, t)| t.iter().any(|&v| v as usize >= nv))
    {
        return Err(invalid_mesh(format!(
            "triangle {f} refers to vertex {} but the mesh has {nv} vertices",
            t.iter().copied().max().unwrap_or(0)
        )));
    }
    if let Some((i, v)) = mesh
        .vertices
        .iter()
        .enumerate()
        .find(|(_, p)| p.iter().any(|c| !c.is_finite()))
    {
        return Err(invalid_mesh(format!(
            "vertex {i} has a non-finite coordinate ({}, {}, {})",
            v[0], v[1], v[2]
        )));
    }
    if let Some((i, d)) = density.iter().enumerate().find(|(_, d)| !d.is_finite()) {
        return Err(invalid_mesh(format!(
            "vertex {i} has a non-finite density ({d}); densities must be finite numbers"
        )));
    }
    Ok(density)
}

fn triangle_area(p: &[[f64; 3]], t: [u32; 3]) -> f64 {
    let [a, b, c] = t.map(|i| p[i as usize]);
    area(a, b, c)
}

/// The area of the triangle `a b c`.
pub(crate) fn area(a: [f64; 3], b: [f64; 3], c: [f64; 3]) -> f64 {
    0.5 * norm(cross(sub(b, a), sub(c, a)))
}

/// Area-weighted quantile of `(value, weight)` pairs sorted by value: the smallest value
/// whose cumulative weight reaches `q` of the total.
fn weighted_quantile(sorted: &[(f64, f64)], total: f64, q: f64) -> f64 {
    let target = q * total;
    let mut acc = 0.0;
    for &(v, w) in sorted {
        acc += w;
        if acc >= target {
            return v;
        }
    }
    sorted.last().map_or(0.0, |&(v, _)| v)
}

/// Each vertex's density with its share of the surrounding area (a third of each incident
/// triangle's area), sorted by density; and the total area.
fn weighted_densities(mesh: &Mesh, density: &[f32]) -> (Vec<(f64, f64)>, f64) {
    let mut weight = vec![0.0f64; mesh.vertices.len()];
    for &t in &mesh.triangles {
        let a = triangle_area(&mesh.vertices, t) / 3.0;
        for v in t {
            weight[v as usize] += a;
        }
    }
    let mut pairs: Vec<(f64, f64)> = density
        .iter()
        .zip(&weight)
        .filter(|(_, &w)| w > 0.0)
        .map(|(&d, &w)| (f64::from(d), w))
        .collect();
    pairs.par_sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    let total = pairs.iter().map(|p| p.1).sum();
    (pairs, total)
}

/// [`auto_threshold`] keeps surface down to at least this many density units below the
/// typical (median) density: a quarter of the typical number of samples per area.
pub const AUTO_MIN_OFFSET: f64 = 1.0;
/// [`auto_threshold`] keeps surface down to at least this many median absolute deviations
/// below the median density, so that unevenly sampled scans keep their sparse parts.
pub const AUTO_MAD_FACTOR: f64 = 4.0;

/// The threshold [`Threshold::Auto`] uses for `mesh`: `V = m − max(AUTO_MIN_OFFSET,
/// AUTO_MAD_FACTOR × MAD)`, where `m` is the area-weighted median of the vertex densities
/// (each vertex weighted by a third of the area of its triangles) and MAD the area-weighted
/// median of `|density − m|`.
///
/// **Why.** The density is a log scale of the local number of samples per area (one unit =
/// 4×). Surface that was sampled sits in a narrow peak around `m`; surface the method
/// invented has density falling with the distance to the nearest samples. At the rim of a
/// real opening the surface still has samples on one side only, about half the typical
/// number, 0.5 units below `m`; sampling noise adds a few tenths. One unit below `m` (a
/// quarter of the typical samples per area) is therefore clear of sampled surface, yet close
/// enough to open modest openings: the closure of the Stanford bunny's bottom holes only
/// dips 1 to 2.4 units below `m` with 100,000 samples, at most 1.6 with 20,000. Unevenly
/// sampled scans have a wide peak, and 4 MADs (about 2.7 standard deviations of a normal
/// peak) keeps their sparse parts. The median stands for the sampled surface as long as
/// that is most of the mesh's area, which held in every case measured (69 % to 84 % for a
/// synthetic terrain, room, facade and dome).
///
/// **Measured** (depth 8 unless said; `bench/trim/` and the tests):
///
/// * Closed, fully sampled shapes lose nothing: the lowest vertex density lies 0.20 to 0.38
///   below `m` for the analytic sphere, Spot, Fandisk (sharp edges), the rocker arm and the
///   CGAL kitten; Spot sampled 20:1 unevenly has MAD 0.53, so `V = m − 2.1`, below its
///   lowest vertex (`m − 1.7`).
/// * `bunny_100k` (ground truth open at the bottom): `V = m − 1` opens 4 of the ground
///   truth's 5 bottom holes (the smallest, 5 % of the diagonal across, stays closed), every
///   new boundary within about 1 % of the diagonal of the ground truth's rim; the mean distance
///   from the mesh to the ground truth falls from 5.5e-5 to 2.1e-5 and the other direction
///   does not change.
///
/// **Limit.** A gap in the scan of a surface that continues (an occlusion) looks exactly
/// like an opening: no samples. The fill of a large gap has *lower* density than a small
/// opening's closure, so no threshold opens the bunny's bottom and keeps the fill of
/// `bunny_100k_hole`'s gap (a ball of radius 10 % of the diagonal: fill densities 3.3 to
/// 0.3 below `m` with 100,000 samples, 2.6 to 0.3 with 20,000); `auto` removes most of that
/// fill. To keep such fills, trim at a lower value, below the fill's density (e.g. `m − 3.5`
/// for that gap: the median is printed by `spsr trim -v`).
///
/// # Errors
/// [`Error::InvalidMesh`] if the mesh has no usable density (see [`trim`]).
pub fn auto_threshold(mesh: &Mesh) -> Result<AutoThreshold> {
    let density = check_mesh(mesh)?;
    let (pairs, total) = weighted_densities(mesh, density);
    if !(total > 0.0 && total.is_finite()) {
        return Err(no_area());
    }
    let median = weighted_quantile(&pairs, total, 0.5);
    let mut dev: Vec<(f64, f64)> = pairs
        .iter()
        .map(|&(d, w)| ((d - median).abs(), w))
        .collect();
    dev.par_sort_unstable_by(|a, b| a.0.total_cmp(&b.0).then(a.1.total_cmp(&b.1)));
    let mad = weighted_quantile(&dev, total, 0.5);
    let threshold = (median - (AUTO_MAD_FACTOR * mad).max(AUTO_MIN_OFFSET)) as f32;
    let below = pairs
        .iter()
        .take_while(|p| p.0 < f64::from(threshold))
        .fold(0.0, |acc, p| acc + p.1);
    Ok(AutoThreshold {
        threshold,
        median,
        mad,
        area_below: below / total,
    })
}

/// The mesh after cutting: triangles on either side of the iso-line, and the new vertices
/// as (lower index, higher index, parameter from the lower towards the higher).
struct Cut {
    triangles: Vec<[u32; 3]>,
    keep: Vec<bool>,
    new_vertices: Vec<(u32, u32, f64)>,
    positions: Vec<[f64; 3]>,
}

/// What cutting a triangle needs of a mesh (whole in memory here, or a slab at a time in
/// `crate::slabs`): each vertex's signed distance `s` to the level and its position, and the
/// vertex on an edge crossed by the level, made when the edge is first met.
pub(crate) trait CutMesh {
    /// Density − threshold at vertex `v`.
    fn s(&self, v: u32) -> f64;
    /// The position of vertex `v` (also of a vertex made on an edge).
    fn position(&self, v: u32) -> [f64; 3];
    /// The vertex where the level crosses the edge `lo hi` (`lo < hi`), at the parameter
    /// `s(lo) / (s(lo) − s(hi))` from `lo`: made on the first call, the same afterwards.
    fn on_edge(&mut self, lo: u32, hi: u32) -> u32;
}

/// The point at parameter `u` from `a` towards `b`.
pub(crate) fn lerp(a: [f64; 3], b: [f64; 3], u: f64) -> [f64; 3] {
    std::array::from_fn(|k| a[k] + u * (b[k] - a[k]))
}

/// The parameter of the level's crossing from `lo` towards `hi` (computed from the
/// lower-numbered end, so that both triangles of the edge agree).
pub(crate) fn crossing(s_lo: f64, s_hi: f64) -> f64 {
    s_lo / (s_lo - s_hi)
}

/// Cuts triangle `t` along the level `s = 0`: appends the pieces with their side (kept or
/// not) to `out`.
pub(crate) fn cut_triangle(mesh: &mut impl CutMesh, t: [u32; 3], out: &mut Vec<([u32; 3], bool)>) {
    let sv = t.map(|v| mesh.s(v));
    let pos = sv.iter().filter(|&&x| x > 0.0).count();
    let neg = sv.iter().filter(|&&x| x < 0.0).count();
    if pos == 0 || neg == 0 {
        // Entirely on one side; a triangle with every vertex exactly on the line has no
        // positive vertex and is discarded, as the reference keeps only values above.
        out.push((t, pos > 0));
        return;
    }
    let mut kept: Vec<u32> = Vec::with_capacity(4);
    let mut dropped: Vec<u32> = Vec::with_capacity(4);
    for k in 0..3 {
        let (a, b) = (t[k], t[(k + 1) % 3]);
        let (sa, sb) = (sv[k], sv[(k + 1) % 3]);
        if sa >= 0.0 {
            kept.push(a);
        }
        if sa <= 0.0 {
            dropped.push(a);
        }
        if (sa > 0.0 && sb < 0.0) || (sa < 0.0 && sb > 0.0) {
            let c = mesh.on_edge(a.min(b), a.max(b));
            kept.push(c);
            dropped.push(c);
        }
    }
    for (poly, side) in [(&kept, true), (&dropped, false)] {
        match poly.len() {
            3 => out.push(([poly[0], poly[1], poly[2]], side)),
            4 => {
                let p = |i: usize| mesh.position(poly[i]);
                // The shorter diagonal gives the better-shaped pair of triangles.
                let (first, second) = if norm2(sub(p(2), p(0))) <= norm2(sub(p(3), p(1))) {
                    ([poly[0], poly[1], poly[2]], [poly[0], poly[2], poly[3]])
                } else {
                    ([poly[1], poly[2], poly[3]], [poly[1], poly[3], poly[0]])
                };
                out.extend([(first, side), (second, side)]);
            }
            _ => {} // a side that is only a vertex or an edge of the triangle
        }
    }
}

/// A mesh in memory being cut: the original vertices, then the new ones.
struct InMemory<'a> {
    s: &'a [f64],
    nv: usize,
    positions: Vec<[f64; 3]>,
    new_vertices: Vec<(u32, u32, f64)>,
    made: FxHashMap<(u32, u32), u32>,
}

impl CutMesh for InMemory<'_> {
    fn s(&self, v: u32) -> f64 {
        self.s[v as usize]
    }

    fn position(&self, v: u32) -> [f64; 3] {
        self.positions[v as usize]
    }

    fn on_edge(&mut self, lo: u32, hi: u32) -> u32 {
        if let Some(&c) = self.made.get(&(lo, hi)) {
            return c;
        }
        let u = crossing(self.s[lo as usize], self.s[hi as usize]);
        let p = lerp(self.positions[lo as usize], self.positions[hi as usize], u);
        self.positions.push(p);
        self.new_vertices.push((lo, hi, u));
        let c = (self.nv + self.new_vertices.len() - 1) as u32;
        self.made.insert((lo, hi), c);
        c
    }
}

/// Splits every triangle crossed by the iso-line `s = 0`, where `s` is density − threshold.
fn cut(mesh: &Mesh, s: &[f64]) -> Cut {
    let n = mesh.triangles.len() + mesh.triangles.len() / 8;
    let mut m = InMemory {
        s,
        nv: mesh.vertices.len(),
        positions: mesh.vertices.clone(),
        new_vertices: Vec::new(),
        made: FxHashMap::default(),
    };
    let mut triangles = Vec::with_capacity(n);
    let mut keep = Vec::with_capacity(n);
    let mut pieces = Vec::with_capacity(4);
    for &t in &mesh.triangles {
        pieces.clear();
        cut_triangle(&mut m, t, &mut pieces);
        for &(t, side) in &pieces {
            triangles.push(t);
            keep.push(side);
        }
    }
    Cut {
        triangles,
        keep,
        new_vertices: m.new_vertices,
        positions: m.positions,
    }
}

pub(crate) fn find(parent: &mut [u32], mut x: u32) -> u32 {
    while parent[x as usize] != x {
        let p = parent[x as usize];
        parent[x as usize] = parent[p as usize];
        x = p;
    }
    x
}

/// Joins the sets of `a` and `b`; the lower root survives, so the result does not depend on
/// the order of the calls.
pub(crate) fn union(parent: &mut [u32], a: u32, b: u32) -> u32 {
    let (ra, rb) = (find(parent, a), find(parent, b));
    let (lo, hi) = if ra < rb { (ra, rb) } else { (rb, ra) };
    parent[hi as usize] = lo;
    lo
}

/// The outcome of the island and hole step.
struct Selection {
    keep: Vec<bool>,
    islands_removed: usize,
    holes_filled: usize,
}

/// The edge-connected components of each side of the cut and their neighbour graph.
pub(crate) struct Components {
    /// Component of each triangle, numbered in the order of their first triangle.
    pub of_triangle: Vec<u32>,
    /// Area of each component.
    pub area: Vec<f64>,
    /// Side of each component (kept or not).
    pub keep: Vec<bool>,
    /// The components on the other side that share an edge with each component.
    pub neighbours: Vec<Vec<u32>>,
}

/// Edge-connected components of each side, their neighbour graph, and the merging of small
/// components into their neighbours (ALGORITHM.md §10 step 2).
fn select(
    triangles: &[[u32; 3]],
    keep: &[bool],
    areas: &[f64],
    total: f64,
    params: &TrimParams,
) -> Selection {
    let mut c = components(triangles, keep, areas);
    let island = params.min_island_area * total;
    let hole = params.hole_area * total;
    let (mut parent, islands_removed, holes_filled) = merge_small(&mut c, island, hole);
    let keep = c
        .of_triangle
        .iter()
        .map(|&t| c.keep[find(&mut parent, t) as usize])
        .collect();
    Selection {
        keep,
        islands_removed,
        holes_filled,
    }
}

/// The components of each side (`keep`) of the triangles, joined across shared edges.
fn components(triangles: &[[u32; 3]], keep: &[bool], areas: &[f64]) -> Components {
    let nf = triangles.len();
    // Every edge with the triangles that use it, grouped by sorting.
    let mut edges: Vec<(u32, u32, u32)> = Vec::with_capacity(3 * nf);
    for (f, t) in triangles.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if a != b {
                edges.push((a.min(b), a.max(b), f as u32));
            }
        }
    }
    // Equal entries are identical, so the order (and the result) does not depend on threads.
    edges.par_sort_unstable();
    let mut face_parent: Vec<u32> = (0..nf as u32).collect();
    let mut across: Vec<(u32, u32)> = Vec::new();
    let mut i = 0;
    while i < edges.len() {
        let mut j = i + 1;
        while j < edges.len() && (edges[j].0, edges[j].1) == (edges[i].0, edges[i].1) {
            j += 1;
        }
        for x in i..j {
            for y in x + 1..j {
                let (f, g) = (edges[x].2, edges[y].2);
                if keep[f as usize] == keep[g as usize] {
                    union(&mut face_parent, f, g);
                } else {
                    across.push((f, g));
                }
            }
        }
        i = j;
    }
    drop(edges);
    // Components numbered in the order of their first triangle. A set's root is its lowest
    // triangle, so `comp_of[root]` is set (to the new number) before any other member asks.
    let mut comp_of = vec![u32::MAX; nf];
    let mut comp_area: Vec<f64> = Vec::new();
    let mut comp_keep: Vec<bool> = Vec::new();
    for f in 0..nf {
        let r = find(&mut face_parent, f as u32) as usize;
        if comp_of[r] == u32::MAX {
            comp_of[r] = comp_area.len() as u32;
            comp_area.push(0.0);
            comp_keep.push(keep[f]);
        }
        let c = comp_of[r];
        comp_of[f] = c;
        comp_area[c as usize] += areas[f];
    }
    drop(face_parent);
    let nc = comp_area.len();
    let mut neighbours: Vec<Vec<u32>> = vec![Vec::new(); nc];
    for &(f, g) in &across {
        let (a, b) = (comp_of[f as usize], comp_of[g as usize]);
        neighbours[a as usize].push(b);
        neighbours[b as usize].push(a);
    }
    drop(across);
    for n in &mut neighbours {
        n.sort_unstable();
        n.dedup();
    }

    Components {
        of_triangle: comp_of,
        area: comp_area,
        keep: comp_keep,
        neighbours,
    }
}

/// Merges components smaller than `island` (kept) or `hole` (discarded) area into their
/// neighbours, smallest first, each switching side; then removes kept pieces below `island`
/// with no neighbour at all. Returns the union-find forest over the components and the
/// numbers of islands removed and holes filled.
pub(crate) fn merge_small(c: &mut Components, island: f64, hole: f64) -> (Vec<u32>, usize, usize) {
    let Components {
        area: comp_area,
        keep: comp_keep,
        neighbours,
        ..
    } = c;
    let nc = comp_area.len();
    let small = |area: f64, keep: bool| if keep { area < island } else { area < hole };
    let mut parent: Vec<u32> = (0..nc as u32).collect();
    // Lazy min-heap over (area, component): entries whose area no longer matches are stale.
    // Areas are non-negative, so their bit patterns order like the values.
    let mut heap: BinaryHeap<Reverse<(u64, u32)>> = (0..nc)
        .filter(|&c| small(comp_area[c], comp_keep[c]) && !neighbours[c].is_empty())
        .map(|c| Reverse((comp_area[c].to_bits(), c as u32)))
        .collect();
    let mut islands_removed = 0;
    let mut holes_filled = 0;
    while let Some(Reverse((bits, c))) = heap.pop() {
        if parent[c as usize] != c || comp_area[c as usize].to_bits() != bits {
            continue;
        }
        // The live neighbours: stale entries point into merged components.
        let mut live: Vec<u32> = std::mem::take(&mut neighbours[c as usize])
            .into_iter()
            .map(|n| find(&mut parent, n))
            .filter(|&n| n != c)
            .collect();
        live.sort_unstable();
        live.dedup();
        if live.is_empty() {
            continue;
        }
        if comp_keep[c as usize] {
            islands_removed += 1;
        } else {
            holes_filled += 1;
        }
        // `c` changes side and joins its neighbours, which all lie on the other side.
        let side = !comp_keep[c as usize];
        let mut root = c;
        let mut area = comp_area[c as usize];
        let mut lists = Vec::with_capacity(live.len());
        for &n in &live {
            area += comp_area[n as usize];
            lists.push(std::mem::take(&mut neighbours[n as usize]));
            root = union(&mut parent, root, n);
        }
        // The neighbours' lists, the longest one extended by the others (entries that now
        // point inside the merged component, or twice to one neighbour, are resolved when
        // the list is next read), so each entry is copied O(log n) times in all.
        let longest = (0..lists.len())
            .max_by_key(|&i| (lists[i].len(), Reverse(i)))
            .unwrap_or(0);
        let mut merged = lists.swap_remove(longest);
        for l in lists {
            merged.extend(l);
        }
        comp_area[root as usize] = area;
        comp_keep[root as usize] = side;
        neighbours[root as usize] = merged;
        if small(area, side) {
            heap.push(Reverse((area.to_bits(), root)));
        }
    }
    // Kept pieces with no discarded neighbour at all (separate parts of the mesh).
    for c in 0..nc {
        if parent[c] == c as u32 && comp_keep[c] && comp_area[c] < island {
            let isolated = std::mem::take(&mut neighbours[c])
                .into_iter()
                .all(|n| find(&mut parent, n) == c as u32);
            if isolated {
                comp_keep[c] = false;
                islands_removed += 1;
            }
        }
    }
    (parent, islands_removed, holes_filled)
}

/// Trims `mesh` at a density level (see the [module documentation](self)).
///
/// # Errors
/// [`Error::InvalidParameter`] for invalid parameters ([`TrimParams::validate`]);
/// [`Error::InvalidMesh`] if the mesh has no density, a non-finite density or coordinate,
/// per-vertex arrays of the wrong length, an index out of range, no triangles or no area.
pub fn trim(mesh: &Mesh, params: &TrimParams) -> Result<(Mesh, TrimStats)> {
    params.validate()?;
    let density = check_mesh(mesh)?;
    let (threshold, auto) = match params.threshold {
        Threshold::Value(v) => (v, None),
        Threshold::Auto => {
            let a = auto_threshold(mesh)?;
            (a.threshold, Some(a))
        }
    };
    let v = f64::from(threshold);
    let s: Vec<f64> = density.iter().map(|&d| f64::from(d) - v).collect();
    let cut = cut(mesh, &s);
    let areas: Vec<f64> = cut
        .triangles
        .iter()
        .map(|&t| triangle_area(&cut.positions, t))
        .collect();
    let total: f64 = areas.iter().sum();
    if !(total > 0.0 && total.is_finite()) {
        return Err(no_area());
    }
    let sel = select(&cut.triangles, &cut.keep, &areas, total, params);
    let kept_area = areas
        .iter()
        .zip(&sel.keep)
        .filter(|(_, &k)| k)
        .fold(0.0, |acc, (a, _)| acc + a);
    if kept_area <= 0.0 {
        let (lo, hi) = density
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(lo, hi), &d| {
                (lo.min(d), hi.max(d))
            });
        return Err(keeps_nothing(threshold, (lo, hi)));
    }
    let out = assemble(mesh, &cut, &sel.keep, threshold);
    let stats = TrimStats {
        threshold,
        auto,
        total_area: total,
        kept_area,
        cut_vertices: cut.new_vertices.len(),
        islands_removed: sel.islands_removed,
        holes_filled: sel.holes_filled,
        triangles_in: mesh.triangles.len(),
        triangles_out: out.triangles.len(),
    };
    Ok((out, stats))
}

/// The normal at parameter `u` from `na` towards `nb`: the direction interpolated and
/// renormalised, the length interpolated, so that unit normals stay unit and weighted ones
/// keep their interpolated weight.
pub(crate) fn interpolate_normal(na: [f32; 3], nb: [f32; 3], u: f64) -> [f32; 3] {
    let na: [f64; 3] = na.map(f64::from);
    let nb: [f64; 3] = nb.map(f64::from);
    let m: [f64; 3] = lerp(na, nb, u);
    let (la, lb, lm) = (norm(na), norm(nb), norm(m));
    let len = la + u * (lb - la);
    if lm > 0.0 {
        m.map(|x| (x / lm * len) as f32)
    } else {
        m.map(|x| x as f32)
    }
}

/// The kept triangles with their vertices (original ones in order, then the cut vertices),
/// every per-vertex value carried over or interpolated.
fn assemble(mesh: &Mesh, cut: &Cut, keep: &[bool], threshold: f32) -> Mesh {
    let total = cut.positions.len();
    let nv = mesh.vertices.len();
    let mut new_index = vec![u32::MAX; total];
    for (t, _) in cut.triangles.iter().zip(keep).filter(|(_, &k)| k) {
        for &v in t {
            new_index[v as usize] = 0;
        }
    }
    let used: Vec<u32> = (0..total as u32)
        .filter(|&v| new_index[v as usize] == 0)
        .collect();
    for (i, &v) in used.iter().enumerate() {
        new_index[v as usize] = i as u32;
    }
    let triangles = cut
        .triangles
        .iter()
        .zip(keep)
        .filter(|(_, &k)| k)
        .map(|(t, _)| t.map(|v| new_index[v as usize]))
        .collect();
    // Source of each output vertex: an original vertex, or a point on an edge.
    let source = |v: u32| -> (u32, u32, f64) {
        if (v as usize) < nv {
            (v, v, 0.0)
        } else {
            cut.new_vertices[v as usize - nv]
        }
    };
    let vertices = used.iter().map(|&v| cut.positions[v as usize]).collect();
    let density = mesh.density.as_ref().map(|d| {
        used.iter()
            .map(|&v| {
                if (v as usize) < nv {
                    d[v as usize]
                } else {
                    // The cut vertices lie on the iso-line by construction.
                    threshold
                }
            })
            .collect()
    });
    let normals = mesh.normals.as_ref().map(|n| {
        used.iter()
            .map(|&v| {
                let (a, b, u) = source(v);
                if a == b {
                    return n[a as usize];
                }
                interpolate_normal(n[a as usize], n[b as usize], u)
            })
            .collect()
    });
    let attributes = mesh
        .attributes
        .iter()
        .map(|a| {
            let data: &AttributeData = &a.data;
            let values = used.iter().map(|&v| {
                let (x, y, u) = source(v);
                let va = data.get(x as usize).unwrap_or(0.0);
                if x == y {
                    va
                } else {
                    let vb = data.get(y as usize).unwrap_or(0.0);
                    va + u * (vb - va)
                }
            });
            Attribute::new(a.name.clone(), data.like_from_f64(values))
        })
        .collect();
    Mesh {
        vertices,
        triangles,
        density,
        normals,
        attributes,
    }
}
