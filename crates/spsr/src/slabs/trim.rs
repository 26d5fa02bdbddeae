//! The end of a slab run whose mesh is written as the slabs produce it (`output::MeshFiles`),
//! for the two steps that need the whole mesh: the removal of small pieces (stage 9,
//! `pipeline::fragments`, with adaptive noise) and density trimming (`crate::trim`). Both are
//! done from the work files a slab at a time, so that the mesh is never whole in memory, and
//! both give the mesh that the same steps give on the slabs' mesh assembled in memory, byte
//! for byte: every sum runs in the order of the run in memory.
//!
//! What stays in memory is a few bytes per vertex (a union–find forest for the pieces, one bit
//! for each vertex kept), the vertices on the faces between slabs (and the trimming's new
//! vertices on the edges there), one component per connected piece of each side of the cut,
//! and one slab at a time. The rest goes through files in the work folder:
//!
//! 1. **Pieces** (stage 9): a union–find over the vertices, triangle after triangle; then each
//!    piece's area, in triangle order; the vertices of the pieces below
//!    [`fragments::MIN_PIECE_AREA`] of the total are marked, and their triangles are skipped
//!    from then on.
//! 2. **Automatic threshold** ([`crate::trim::auto_threshold`]): each vertex's area weight,
//!    slab by slab (the vertices on a shared face gather theirs across both slabs, in
//!    triangle order); each slab's `(density, weight)` pairs sorted into a run file; the
//!    weighted median and the median absolute deviation are read off the runs merged in
//!    order, as the sorted list in memory gives them.
//! 3. **Cut** (`crate::trim::cut_triangle`): slab by slab, in triangle order, so that the new
//!    vertices are numbered as in memory; a new vertex on an edge between two face vertices
//!    is kept for the other slab. The new vertices and the cut triangles (with their area)
//!    go to files; each slab's triangles are joined across their edges into components per
//!    side, and the components of two slabs across the edges of their shared face.
//! 4. **Islands and holes** (`crate::trim::merge_small`) on the components, numbered by
//!    their first triangle and their areas summed in triangle order, as in memory.
//! 5. **Writing**: the vertices some kept triangle uses, in order (the original ones, then the
//!    new ones), renumbered by rank; the kept triangles; the checks (pieces, open edges) on
//!    the way.

use std::cmp::{Ordering, Reverse};
use std::collections::BinaryHeap;
use std::fs::File;
use std::io::{BufReader, BufWriter, Read, Write};
use std::path::{Path, PathBuf};

use rayon::slice::ParallelSliceMut;
use rustc_hash::FxHashMap;

use super::output::{for_each_record, pieces, put_triangle, Layout, Slab, Stored, Written};
use super::spill::io_err;
use crate::pipeline::fragments::MIN_PIECE_AREA;
use crate::trim::{
    area, crossing, cut_triangle, find, interpolate_normal, keeps_nothing, lerp, merge_small,
    no_area, union, AutoThreshold, Components, CutMesh, Threshold, TrimParams, TrimStats,
    AUTO_MAD_FACTOR, AUTO_MIN_OFFSET,
};
use crate::{Error, Result};

/// What [`finish`] did.
pub(crate) struct Finished {
    pub written: Written,
    /// The trimming's figures (with trimming).
    pub trimmed: Option<TrimStats>,
    /// Small pieces removed (with `fragments`).
    pub fragments: usize,
}

/// Writes the stored mesh to `path` (binary PLY): without the pieces below
/// [`MIN_PIECE_AREA`] of its area when `fragments` (as `pipeline::fragments` does in memory),
/// then trimmed with `trim`; the density is written when `density` (and stored).
pub(crate) fn finish(
    mut stored: Stored,
    path: &Path,
    fragments: bool,
    trim: Option<&TrimParams>,
    density: bool,
) -> Result<Finished> {
    let small = if fragments {
        small_pieces(&mut stored)?
    } else {
        None
    };
    let count = small.as_ref().map_or(0, |s| s.1);
    let dropped = small.as_ref().map(|s| &s.0);
    let Some(params) = trim else {
        let written = match dropped {
            None => stored.write(path, density)?,
            Some(d) => write(&stored, &Selection::Pieces(d), path, density)?,
        };
        return Ok(Finished {
            written,
            trimmed: None,
            fragments: count,
        });
    };
    params.validate()?;
    if !stored.layout.density {
        return Err(Error::MissingDensity);
    }
    let (threshold, auto) = match params.threshold {
        Threshold::Value(v) => (v, None),
        Threshold::Auto => {
            let a = auto_threshold(&stored, dropped)?;
            (a.threshold, Some(a))
        }
    };
    let result = cut(&stored, dropped, threshold)
        .and_then(|cut| select_and_write(&stored, &cut, params, threshold, auto, path, density));
    remove_cut_files(&stored.dir);
    let (written, trimmed) = result?;
    Ok(Finished {
        written,
        trimmed: Some(trimmed),
        fragments: count,
    })
}

/// One bit per vertex.
pub(crate) struct Bits(Vec<u64>);

impl Bits {
    fn new(n: u64) -> Bits {
        Bits(vec![0; n.div_ceil(64) as usize])
    }

    fn set(&mut self, i: u32) {
        self.0[(i >> 6) as usize] |= 1 << (i & 63);
    }

    fn get(&self, i: u32) -> bool {
        (self.0[(i >> 6) as usize] >> (i & 63)) & 1 == 1
    }
}

/// The new numbers of the vertices whose bit is set: their ranks.
struct Ranks {
    bits: Bits,
    /// Set bits before each word.
    before: Vec<u32>,
}

impl Ranks {
    fn new(bits: Bits) -> Ranks {
        let mut before = Vec::with_capacity(bits.0.len());
        let mut n = 0u32;
        for w in &bits.0 {
            before.push(n);
            n += w.count_ones();
        }
        Ranks { bits, before }
    }

    fn count(&self) -> u64 {
        self.before.last().map_or(0, |&n| u64::from(n))
            + self.bits.0.last().map_or(0, |w| u64::from(w.count_ones()))
    }

    fn rank(&self, i: u32) -> u32 {
        let w = (i >> 6) as usize;
        self.before[w] + (self.bits.0[w] & ((1u64 << (i & 63)) - 1)).count_ones()
    }
}

/// Slab `s` without the triangles of the pieces marked in `dropped`.
fn slab<'a>(stored: &'a Stored, s: usize, dropped: Option<&Bits>) -> Result<Slab<'a>> {
    let mut slab = stored.slab(s)?;
    if let Some(d) = dropped {
        slab.triangles.retain(|t| !d.get(t[0]));
    }
    Ok(slab)
}

/// The area of triangle `t` of a slab.
fn slab_area(layout: &Layout, slab: &Slab, t: [u32; 3]) -> f64 {
    let [a, b, c] = t.map(|v| layout.position(slab.record(v)));
    area(a, b, c)
}

/// The vertices of the pieces (triangles sharing a vertex) smaller than [`MIN_PIECE_AREA`] of
/// the mesh's area, and how many such pieces there are; none when the mesh is one piece, or
/// when no piece or every piece is small (`pipeline::fragments::remove_fragments`).
fn small_pieces(stored: &mut Stored) -> Result<Option<(Bits, usize)>> {
    // The pieces were joined as the slabs came: a mesh of one piece is left as it is.
    if pieces(&mut stored.parent) < 2 {
        return Ok(None);
    }
    let mut parent = std::mem::take(&mut stored.parent);
    let found = pieces_below(stored, &mut parent);
    stored.parent = parent;
    found
}

/// [`small_pieces`] of a mesh of several pieces (`parent`: its forest).
fn pieces_below(stored: &Stored, parent: &mut [u32]) -> Result<Option<(Bits, usize)>> {
    let slabs = stored.spans.len();
    // Pieces numbered by their first triangle, each one's area summed in triangle order
    // (`Mesh::pieces`).
    let mut number: FxHashMap<u32, u32> = FxHashMap::default();
    let mut areas: Vec<f64> = Vec::new();
    for s in 0..slabs {
        let slab = stored.slab(s)?;
        for &t in &slab.triangles {
            let r = find(parent, t[0]);
            let p = *number.entry(r).or_insert_with(|| {
                areas.push(0.0);
                areas.len() as u32 - 1
            });
            let a = slab_area(&stored.layout, &slab, t);
            if a.is_finite() {
                areas[p as usize] += a;
            }
        }
    }
    if areas.len() < 2 {
        return Ok(None);
    }
    let total: f64 = areas.iter().sum();
    let small: Vec<bool> = areas.iter().map(|&a| a < MIN_PIECE_AREA * total).collect();
    let count = small.iter().filter(|&&s| s).count();
    if count == 0 || count == areas.len() {
        return Ok(None);
    }
    let mut bits = Bits::new(stored.vertices);
    for v in 0..stored.vertices as u32 {
        let r = find(parent, v);
        if number.get(&r).is_some_and(|&p| small[p as usize]) {
            bits.set(v);
        }
    }
    Ok(Some((bits, count)))
}

/// `(value, weight)` pairs in the order of `crate::trim`'s sorted lists: by value, then by
/// weight.
#[derive(Clone, Copy, PartialEq)]
struct Pair(f64, f64);

impl Eq for Pair {}

impl Ord for Pair {
    fn cmp(&self, other: &Self) -> Ordering {
        self.0.total_cmp(&other.0).then(self.1.total_cmp(&other.1))
    }
}

impl PartialOrd for Pair {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// Sorted runs of pairs in files, read back merged: one sorted list that is never whole in
/// memory.
struct Runs {
    paths: Vec<PathBuf>,
}

impl Runs {
    /// Sorts `pairs` and writes them as a new run, next to `stem`.
    fn add(&mut self, stem: &Path, mut pairs: Vec<Pair>) -> Result<()> {
        pairs.par_sort_unstable();
        let path = stem.with_extension(format!("run{}", self.paths.len()));
        self.paths.push(path.clone());
        let file = File::create(&path).map_err(|e| io_err(&path, e))?;
        let mut w = BufWriter::with_capacity(1 << 16, file);
        for p in pairs {
            w.write_all(&p.0.to_le_bytes())
                .and_then(|_| w.write_all(&p.1.to_le_bytes()))
                .map_err(|e| io_err(&path, e))?;
        }
        w.flush().map_err(|e| io_err(&path, e))
    }

    fn read(path: &Path) -> Result<Vec<Pair>> {
        let bytes = std::fs::read(path).map_err(|e| io_err(path, e))?;
        Ok(bytes
            .chunks_exact(16)
            .map(|c| {
                let f = |i: usize| f64::from_le_bytes(c[i..i + 8].try_into().expect("8"));
                Pair(f(0), f(8))
            })
            .collect())
    }

    /// Every run's pairs mapped by `f` (on the values) into new sorted runs next to `stem`
    /// (removed again if one cannot be made).
    fn map(&self, stem: &Path, f: impl Fn(f64) -> f64) -> Result<Runs> {
        let mut out = Runs { paths: Vec::new() };
        for p in &self.paths {
            let made = Runs::read(p).and_then(|pairs| {
                out.add(stem, pairs.into_iter().map(|q| Pair(f(q.0), q.1)).collect())
            });
            if let Err(e) = made {
                out.remove();
                return Err(e);
            }
        }
        Ok(out)
    }

    /// Calls `f` with the pairs of all runs in order, while it returns true.
    fn merged(&self, mut f: impl FnMut(f64, f64) -> bool) -> Result<()> {
        let mut readers = Vec::with_capacity(self.paths.len());
        for p in &self.paths {
            let file = File::open(p).map_err(|e| io_err(p, e))?;
            readers.push((BufReader::with_capacity(1 << 16, file), p));
        }
        let next = |r: &mut (BufReader<File>, &PathBuf)| -> Result<Option<Pair>> {
            let mut b = [0u8; 16];
            match r.0.read_exact(&mut b) {
                Ok(()) => {
                    let g = |i: usize| f64::from_le_bytes(b[i..i + 8].try_into().expect("8"));
                    Ok(Some(Pair(g(0), g(8))))
                }
                Err(e) if e.kind() == std::io::ErrorKind::UnexpectedEof => Ok(None),
                Err(e) => Err(io_err(r.1, e)),
            }
        };
        let mut heap = BinaryHeap::with_capacity(readers.len());
        for (i, r) in readers.iter_mut().enumerate() {
            if let Some(p) = next(r)? {
                heap.push(Reverse((p, i)));
            }
        }
        // Equal pairs are identical, so the order among runs does not matter.
        while let Some(Reverse((p, i))) = heap.pop() {
            if !f(p.0, p.1) {
                break;
            }
            if let Some(q) = next(&mut readers[i])? {
                heap.push(Reverse((q, i)));
            }
        }
        Ok(())
    }

    /// The smallest value whose cumulative weight reaches `q` of `total` (`crate::trim`'s
    /// weighted quantile).
    fn quantile(&self, total: f64, q: f64) -> Result<f64> {
        let target = q * total;
        let (mut acc, mut last, mut found) = (0.0, 0.0, None);
        self.merged(|v, w| {
            acc += w;
            last = v;
            if acc >= target {
                found = Some(v);
            }
            found.is_none()
        })?;
        Ok(found.unwrap_or(last))
    }

    fn remove(self) {
        for p in self.paths {
            let _ = std::fs::remove_file(p);
        }
    }
}

/// [`crate::trim::auto_threshold`] of the stored mesh (without the `dropped` pieces).
fn auto_threshold(stored: &Stored, dropped: Option<&Bits>) -> Result<AutoThreshold> {
    let layout = &stored.layout;
    let stem = stored.dir.join("trim-densities");
    let mut runs = Runs { paths: Vec::new() };
    let result = (|| {
        // A face vertex gathers its weight across the slabs that use it, in triangle order.
        let mut face_weight: FxHashMap<u32, f64> = FxHashMap::default();
        for s in 0..stored.spans.len() {
            let slab = slab(stored, s, dropped)?;
            let mut weight = vec![0.0f64; slab.count()];
            for &t in &slab.triangles {
                let a = slab_area(layout, &slab, t) / 3.0;
                for v in t {
                    if stored.face_records.contains_key(&v) {
                        *face_weight.entry(v).or_insert(0.0) += a;
                    } else {
                        weight[(v - slab.first) as usize] += a;
                    }
                }
            }
            let pairs = (0..weight.len())
                .filter(|&i| weight[i] > 0.0)
                .map(|i| {
                    let d = layout.density(slab.record(slab.first + i as u32));
                    Pair(f64::from(d), weight[i])
                })
                .collect();
            runs.add(&stem, pairs)?;
        }
        let faces = face_weight
            .iter()
            .filter(|(_, &w)| w > 0.0)
            .map(|(v, &w)| Pair(f64::from(layout.density(&stored.face_records[v])), w))
            .collect();
        runs.add(&stem, faces)?;
        threshold_of(&runs, &stored.dir.join("trim-deviations"))
    })();
    runs.remove();
    result
}

/// The automatic threshold from the sorted runs of `(density, weight)` pairs.
fn threshold_of(runs: &Runs, stem: &Path) -> Result<AutoThreshold> {
    let mut total = 0.0;
    runs.merged(|_, w| {
        total += w;
        true
    })?;
    if !(total > 0.0 && f64::is_finite(total)) {
        return Err(no_area());
    }
    let median = runs.quantile(total, 0.5)?;
    let deviations = runs.map(stem, |d| (d - median).abs())?;
    let mad = deviations.quantile(total, 0.5);
    deviations.remove();
    let mad = mad?;
    let threshold = (median - (AUTO_MAD_FACTOR * mad).max(AUTO_MIN_OFFSET)) as f32;
    let mut below = 0.0;
    runs.merged(|d, w| {
        let under = d < f64::from(threshold);
        if under {
            below += w;
        }
        under
    })?;
    Ok(AutoThreshold {
        threshold,
        median,
        mad,
        area_below: below / total,
    })
}

/// The work files of the cut mesh.
const CUT_VERTICES: &str = "trim.vertices";
const CUT_TRIANGLES: &str = "trim.triangles";
/// A cut triangle's record: its three vertices (`u32`), its component (`u32`) and its area
/// (`f64`).
const CUT_RECORD: usize = 24;

/// The mesh cut along the level, in the work folder.
struct CutFiles {
    /// New vertices (in [`CUT_VERTICES`], records of the stored layout).
    vertices: u64,
    /// Each slab's cut triangles in [`CUT_TRIANGLES`]: first and count.
    spans: Vec<(u64, u64)>,
    /// The side of each component (of a slab's triangles joined across their edges; numbered
    /// by their first triangle over all slabs).
    sides: Vec<bool>,
    /// Pairs of components of one side that share an edge of a shared face.
    joined: Vec<(u32, u32)>,
    /// Pairs of components of opposite sides that share an edge.
    across: Vec<(u32, u32)>,
    /// The new vertices on the edges of the shared faces, by index: their records.
    face_new: FxHashMap<u32, Vec<u8>>,
    /// The area of the cut mesh, summed in triangle order.
    total_area: f64,
    /// Triangles before cutting.
    triangles_in: u64,
    /// The range of the vertices' densities (for the message when nothing is kept).
    densities: (f32, f32),
}

fn remove_cut_files(dir: &Path) {
    let _ = std::fs::remove_file(dir.join(CUT_VERTICES));
    let _ = std::fs::remove_file(dir.join(CUT_TRIANGLES));
}

impl CutFiles {
    /// Calls `f` with each cut triangle of slab `s`: its vertices, component and area.
    fn for_each_triangle(
        &self,
        dir: &Path,
        s: usize,
        mut f: impl FnMut([u32; 3], u32, f64),
    ) -> Result<()> {
        let (first, count) = self.spans[s];
        let mut raw = vec![0u8; count as usize * CUT_RECORD];
        super::output::read_at(
            &dir.join(CUT_TRIANGLES),
            first * CUT_RECORD as u64,
            &mut raw,
        )?;
        for r in raw.chunks_exact(CUT_RECORD) {
            let u = |i: usize| u32::from_le_bytes(r[i * 4..i * 4 + 4].try_into().expect("4"));
            let a = f64::from_le_bytes(r[16..24].try_into().expect("8"));
            f([u(0), u(1), u(2)], u(3), a);
        }
        Ok(())
    }
}

/// One slab being cut: its vertices, the new vertices made so far.
struct SlabCut<'a, 'b> {
    layout: &'a Layout,
    slab: &'a Slab<'b>,
    stored: &'a Stored,
    level: f64,
    threshold: f32,
    /// Vertices in the files (the new ones are numbered after them).
    nv: u32,
    /// The number of the first new vertex of this slab.
    first_new: u32,
    /// Every new vertex so far (the number of the next one is `first_new + made`).
    next: u32,
    /// The records of this slab's new vertices.
    records: Vec<u8>,
    /// New vertices on the edges within this slab.
    made: FxHashMap<(u32, u32), u32>,
    /// New vertices on the edges of the shared faces (kept for the next slab), and their
    /// records.
    face_made: &'a mut FxHashMap<(u32, u32), u32>,
    face_new: &'a mut FxHashMap<u32, Vec<u8>>,
    out: &'a mut BufWriter<File>,
    failed: Option<std::io::Error>,
}

impl SlabCut<'_, '_> {
    fn record(&self, v: u32) -> &[u8] {
        if v < self.nv {
            self.slab.record(v)
        } else if v >= self.first_new {
            let len = self.layout.len();
            let i = (v - self.first_new) as usize * len;
            &self.records[i..i + len]
        } else {
            &self.face_new[&v]
        }
    }

    fn on_face(&self, v: u32) -> bool {
        self.stored.face_records.contains_key(&v) || self.face_new.contains_key(&v)
    }

    /// The record of the vertex at parameter `u` from `lo` towards `hi`: every value
    /// interpolated as `crate::trim` interpolates it, the density the threshold.
    fn new_record(&self, lo: u32, hi: u32, u: f64) -> Vec<u8> {
        let l = self.layout;
        let (a, b) = (self.record(lo), self.record(hi));
        let mut rec = Vec::with_capacity(l.len());
        for c in lerp(l.position(a), l.position(b), u) {
            rec.extend_from_slice(&c.to_le_bytes());
        }
        if l.normals {
            for c in interpolate_normal(l.normal(a), l.normal(b), u) {
                rec.extend_from_slice(&c.to_le_bytes());
            }
        }
        for (k, (_, ty)) in l.attributes.iter().enumerate() {
            let (va, vb) = (l.attribute(a, k), l.attribute(b, k));
            ty.put_le(va + u * (vb - va), &mut rec);
        }
        rec.extend_from_slice(&self.threshold.to_le_bytes());
        rec
    }
}

impl CutMesh for SlabCut<'_, '_> {
    fn s(&self, v: u32) -> f64 {
        f64::from(self.layout.density(self.record(v))) - self.level
    }

    fn position(&self, v: u32) -> [f64; 3] {
        self.layout.position(self.record(v))
    }

    fn on_edge(&mut self, lo: u32, hi: u32) -> u32 {
        let shared = self.on_face(lo) && self.on_face(hi);
        let known = if shared {
            self.face_made.get(&(lo, hi))
        } else {
            self.made.get(&(lo, hi))
        };
        if let Some(&c) = known {
            return c;
        }
        let u = crossing(self.s(lo), self.s(hi));
        let rec = self.new_record(lo, hi, u);
        let c = self.next;
        self.next += 1;
        if let Err(e) = self.out.write_all(&rec) {
            self.failed.get_or_insert(e);
        }
        self.records.extend_from_slice(&rec);
        if shared {
            self.face_made.insert((lo, hi), c);
            self.face_new.insert(c, rec);
        } else {
            self.made.insert((lo, hi), c);
        }
        c
    }
}

/// Cuts the stored mesh (without the `dropped` pieces) along the level `threshold`, slab by
/// slab, into the work files, and joins the cut triangles into components per side.
fn cut(stored: &Stored, dropped: Option<&Bits>, threshold: f32) -> Result<CutFiles> {
    let dir = &stored.dir;
    let vpath = dir.join(CUT_VERTICES);
    let tpath = dir.join(CUT_TRIANGLES);
    let create = |p: &Path| -> Result<BufWriter<File>> {
        let f = File::create(p).map_err(|e| io_err(p, e))?;
        Ok(BufWriter::with_capacity(1 << 16, f))
    };
    let mut vout = create(&vpath)?;
    let mut tout = create(&tpath)?;
    let nv = stored.vertices as u32;
    // Each triangle adds at most two cut vertices (as `crate::trim` checks).
    if stored.vertices + 2 * stored.triangles > u64::from(u32::MAX) {
        return Err(Error::InvalidMesh(format!(
            "the mesh is too large to trim: {} vertices and {} triangles could need more \
             than 2^32 vertices after cutting",
            stored.vertices, stored.triangles
        )));
    }
    let mut spans = Vec::new();
    let mut sides = Vec::new();
    let mut across = Vec::new();
    let mut face_new = FxHashMap::default();
    let mut total_area = 0.0;
    let mut triangles_in = 0u64;
    let mut densities = (f32::INFINITY, f32::NEG_INFINITY);
    let mut face_made = FxHashMap::default();
    // The components of each shared-face edge's triangles.
    let mut shared_edges: FxHashMap<(u32, u32), Vec<u32>> = FxHashMap::default();
    let mut next = nv;
    let mut written = 0u64;
    for s in 0..stored.spans.len() {
        let slab = slab(stored, s, dropped)?;
        triangles_in += slab.triangles.len() as u64;
        check_slab(stored, &slab, &mut densities)?;
        let mut pieces = Vec::with_capacity(slab.triangles.len() + slab.triangles.len() / 8);
        let mut cutter = SlabCut {
            layout: &stored.layout,
            slab: &slab,
            stored,
            level: f64::from(threshold),
            threshold,
            nv,
            first_new: next,
            next,
            records: Vec::new(),
            made: FxHashMap::default(),
            face_made: &mut face_made,
            face_new: &mut face_new,
            out: &mut vout,
            failed: None,
        };
        for &t in &slab.triangles {
            cut_triangle(&mut cutter, t, &mut pieces);
        }
        if let Some(e) = cutter.failed.take() {
            return Err(io_err(&vpath, e));
        }
        let areas: Vec<f64> = pieces
            .iter()
            .map(|&(t, _)| {
                let [a, b, c] = t.map(|v| cutter.position(v));
                area(a, b, c)
            })
            .collect();
        for a in &areas {
            total_area += a;
        }
        let (component, shared) = components(&cutter, &pieces, &mut sides, &mut across)?;
        next = cutter.next;
        for (e, f) in shared {
            shared_edges
                .entry(e)
                .or_default()
                .push(component[f as usize]);
        }
        for (((t, _), c), a) in pieces.iter().zip(&component).zip(&areas) {
            let mut rec = [0u8; CUT_RECORD];
            for (i, v) in t.iter().chain([c]).enumerate() {
                rec[i * 4..i * 4 + 4].copy_from_slice(&v.to_le_bytes());
            }
            rec[16..24].copy_from_slice(&a.to_le_bytes());
            tout.write_all(&rec).map_err(|e| io_err(&tpath, e))?;
        }
        spans.push((written, pieces.len() as u64));
        written += pieces.len() as u64;
    }
    vout.flush().map_err(|e| io_err(&vpath, e))?;
    tout.flush().map_err(|e| io_err(&tpath, e))?;
    if triangles_in == 0 {
        return Err(Error::InvalidMesh("the mesh has no triangles".into()));
    }
    let mut joined = Vec::new();
    for list in shared_edges.values() {
        for (i, &a) in list.iter().enumerate() {
            for &b in &list[i + 1..] {
                if sides[a as usize] == sides[b as usize] {
                    joined.push((a, b));
                } else {
                    across.push((a, b));
                }
            }
        }
    }
    Ok(CutFiles {
        vertices: u64::from(next - nv),
        spans,
        sides,
        joined,
        across,
        face_new,
        total_area,
        triangles_in,
        densities,
    })
}

/// The checks `crate::trim` makes of a mesh, on one slab's vertices; widens `densities` to
/// theirs.
fn check_slab(stored: &Stored, slab: &Slab, densities: &mut (f32, f32)) -> Result<()> {
    let l = &stored.layout;
    for i in 0..slab.count() as u32 {
        let v = slab.first + i;
        let rec = slab.record(v);
        let p = l.position(rec);
        if p.iter().any(|c| !c.is_finite()) {
            return Err(Error::InvalidMesh(format!(
                "vertex {v} has a non-finite coordinate ({}, {}, {})",
                p[0], p[1], p[2]
            )));
        }
        let d = l.density(rec);
        if !d.is_finite() {
            return Err(Error::InvalidMesh(format!(
                "vertex {v} has a non-finite density ({d}); densities must be finite numbers"
            )));
        }
        *densities = (densities.0.min(d), densities.1.max(d));
    }
    Ok(())
}

/// A shared-face edge of a slab's cut triangles, with the triangle (by its place in the
/// slab).
type SharedEdge = ((u32, u32), u32);

/// Joins a slab's cut triangles of one side across the edges within the slab; returns each
/// triangle's component (numbered after `files.sides`' components, by first triangle) and the
/// edges on the shared faces, which are joined once every slab is cut. Adds the new
/// components' sides to `sides`, and the pairs of components across the cut to `across`.
fn components(
    cutter: &SlabCut,
    pieces: &[([u32; 3], bool)],
    sides: &mut Vec<bool>,
    across_all: &mut Vec<(u32, u32)>,
) -> Result<(Vec<u32>, Vec<SharedEdge>)> {
    let mut edges: Vec<(u32, u32, u32)> = Vec::with_capacity(3 * pieces.len());
    let mut shared = Vec::new();
    for (f, (t, _)) in pieces.iter().enumerate() {
        for k in 0..3 {
            let (a, b) = (t[k], t[(k + 1) % 3]);
            if a == b {
                continue;
            }
            let e = (a.min(b), a.max(b));
            if cutter.on_face(a) && cutter.on_face(b) {
                shared.push((e, f as u32));
            } else {
                edges.push((e.0, e.1, f as u32));
            }
        }
    }
    edges.par_sort_unstable();
    let mut parent: Vec<u32> = (0..pieces.len() as u32).collect();
    let mut across = Vec::new();
    for group in edges.chunk_by(|x, y| (x.0, x.1) == (y.0, y.1)) {
        for (i, x) in group.iter().enumerate() {
            for y in &group[i + 1..] {
                if pieces[x.2 as usize].1 == pieces[y.2 as usize].1 {
                    union(&mut parent, x.2, y.2);
                } else {
                    across.push((x.2, y.2));
                }
            }
        }
    }
    drop(edges);
    // A set's root is its first triangle, numbered before the others ask.
    let mut component = vec![u32::MAX; pieces.len()];
    for f in 0..pieces.len() {
        let r = find(&mut parent, f as u32) as usize;
        if component[r] == u32::MAX {
            component[r] = u32::try_from(sides.len()).map_err(|_| {
                Error::InvalidMesh("too many pieces on the sides of the cut".into())
            })?;
            sides.push(pieces[f].1);
        }
        component[f] = component[r];
    }
    let mut pairs: Vec<(u32, u32)> = across
        .into_iter()
        .map(|(f, g)| {
            let (a, b) = (component[f as usize], component[g as usize]);
            (a.min(b), a.max(b))
        })
        .collect();
    pairs.sort_unstable();
    pairs.dedup();
    across_all.extend(pairs);
    Ok((component, shared))
}

/// Islands and holes on the components of the cut mesh, then the writing of the kept part.
fn select_and_write(
    stored: &Stored,
    cut: &CutFiles,
    params: &TrimParams,
    threshold: f32,
    auto: Option<AutoThreshold>,
    path: &Path,
    density: bool,
) -> Result<(Written, TrimStats)> {
    let dir = &stored.dir;
    let n = cut.sides.len();
    // The slabs' components joined across the shared faces: a set's root is its lowest
    // component, so the sets are numbered by their first triangle, as in memory.
    let mut parent: Vec<u32> = (0..n as u32).collect();
    for &(a, b) in &cut.joined {
        union(&mut parent, a, b);
    }
    let mut number = vec![u32::MAX; n];
    let mut keep = Vec::new();
    let mut whole = vec![0u32; n];
    for c in 0..n {
        let r = find(&mut parent, c as u32) as usize;
        if number[r] == u32::MAX {
            number[r] = keep.len() as u32;
            keep.push(cut.sides[c]);
        }
        whole[c] = number[r];
    }
    drop(parent);
    drop(number);
    let mut areas = vec![0.0f64; keep.len()];
    for s in 0..cut.spans.len() {
        cut.for_each_triangle(dir, s, |_, c, a| areas[whole[c as usize] as usize] += a)?;
    }
    let mut neighbours: Vec<Vec<u32>> = vec![Vec::new(); keep.len()];
    for &(a, b) in &cut.across {
        let (a, b) = (whole[a as usize], whole[b as usize]);
        neighbours[a as usize].push(b);
        neighbours[b as usize].push(a);
    }
    for l in &mut neighbours {
        l.sort_unstable();
        l.dedup();
    }
    let mut comps = Components {
        of_triangle: Vec::new(),
        area: areas,
        keep,
        neighbours,
    };
    let total = cut.total_area;
    if !(total > 0.0 && total.is_finite()) {
        return Err(no_area());
    }
    let (mut merged, islands_removed, holes_filled) = merge_small(
        &mut comps,
        params.min_island_area * total,
        params.hole_area * total,
    );
    let kept: Vec<bool> = whole
        .iter()
        .map(|&c| comps.keep[find(&mut merged, c) as usize])
        .collect();
    drop(comps);
    let mut kept_area = 0.0;
    for s in 0..cut.spans.len() {
        cut.for_each_triangle(dir, s, |_, c, a| {
            if kept[c as usize] {
                kept_area += a;
            }
        })?;
    }
    if kept_area <= 0.0 {
        return Err(keeps_nothing(threshold, cut.densities));
    }
    let written = write(stored, &Selection::Cut(cut, &kept), path, density)?;
    let stats = TrimStats {
        threshold,
        auto,
        total_area: total,
        kept_area,
        cut_vertices: cut.vertices as usize,
        islands_removed,
        holes_filled,
        triangles_in: cut.triangles_in as usize,
        triangles_out: written.triangles as usize,
    };
    Ok((written, stats))
}

/// Which triangles [`write`] writes.
enum Selection<'a> {
    /// The stored triangles but those of the marked pieces.
    Pieces(&'a Bits),
    /// The cut mesh's triangles whose component is kept.
    Cut(&'a CutFiles, &'a [bool]),
}

impl Selection<'_> {
    /// Calls `f` with each triangle written, slab by slab (the slab's index first).
    fn for_each(&self, stored: &Stored, mut f: impl FnMut(usize, [u32; 3])) -> Result<()> {
        for s in 0..stored.spans.len() {
            match self {
                Selection::Pieces(dropped) => {
                    for t in slab(stored, s, Some(dropped))?.triangles {
                        f(s, t);
                    }
                }
                Selection::Cut(cut, kept) => cut.for_each_triangle(&stored.dir, s, |t, c, _| {
                    if kept[c as usize] {
                        f(s, t);
                    }
                })?,
            }
        }
        Ok(())
    }

    /// Whether vertex `v` lies on a shared face (its edges are counted across slabs).
    fn on_face(&self, stored: &Stored, v: u32) -> bool {
        stored.face_records.contains_key(&v)
            || matches!(self, Selection::Cut(cut, _) if cut.face_new.contains_key(&v))
    }

    /// The new vertices (after the stored ones).
    fn new_vertices(&self) -> u64 {
        match self {
            Selection::Pieces(_) => 0,
            Selection::Cut(cut, _) => cut.vertices,
        }
    }
}

/// Writes the selected triangles and the vertices they use, in order and renumbered, to
/// `path` (a binary PLY written atomically), with the checks of the result.
fn write(stored: &Stored, selection: &Selection, path: &Path, density: bool) -> Result<Written> {
    let layout = &stored.layout;
    let nv = stored.vertices;
    let all = nv + selection.new_vertices();
    let mut used = Bits::new(all);
    let mut nt = 0u64;
    selection.for_each(stored, |_, t| {
        for v in t {
            used.set(v);
        }
        nt += 1;
    })?;
    let ranks = Ranks::new(used);
    let new_path = stored.dir.join(CUT_VERTICES);
    let each_vertex = |f: &mut dyn FnMut(&[u8]) -> Result<()>| -> Result<()> {
        let mut v = 0u32;
        let mut pick = |rec: &[u8]| {
            let used = ranks.bits.get(v);
            v += 1;
            if used {
                f(rec)
            } else {
                Ok(())
            }
        };
        stored.for_each_vertex(&mut pick)?;
        if all > nv {
            for_each_record(&new_path, layout.len(), all - nv, &mut pick)?;
        }
        Ok(())
    };
    let mut extent = crate::io::Extent::default();
    each_vertex(&mut |rec| {
        extent.add(layout.position(rec));
        Ok(())
    })?;
    let doubles = extent.needs_f64();
    let count = ranks.count();
    let mut parent: Vec<u32> = (0..count as u32).collect();
    let mut open_edges = 0u64;
    crate::io::write_with(path, |out| {
        let io = |e: Error| std::io::Error::other(e.to_string());
        out.write_all(layout.header(count, nt, doubles, density).as_bytes())?;
        each_vertex(&mut |rec| {
            layout
                .put(out, rec, doubles, density)
                .map_err(|e| io_err(path, e))
        })
        .map_err(io)?;
        // Every edge's triangles, counted within each slab, and across slabs for the edges of
        // the shared faces.
        let mut edges: FxHashMap<(u32, u32), u32> = FxHashMap::default();
        let mut shared: FxHashMap<(u32, u32), u32> = FxHashMap::default();
        let mut current = 0;
        let mut failed = None;
        selection
            .for_each(stored, |s, t| {
                if s != current {
                    open_edges += edges.values().filter(|&&n| n != 2).count() as u64;
                    edges.clear();
                    current = s;
                }
                for k in 0..3 {
                    let (a, b) = (t[k], t[(k + 1) % 3]);
                    let e = (a.min(b), a.max(b));
                    let face = selection.on_face(stored, a) && selection.on_face(stored, b);
                    *if face { &mut shared } else { &mut edges }
                        .entry(e)
                        .or_insert(0) += 1;
                }
                let r = t.map(|v| ranks.rank(v));
                union(&mut parent, r[0], r[1]);
                union(&mut parent, r[1], r[2]);
                if let Err(e) = put_triangle(out, r) {
                    failed.get_or_insert(e);
                }
            })
            .map_err(io)?;
        if let Some(e) = failed {
            return Err(e);
        }
        open_edges += edges.values().filter(|&&n| n != 2).count() as u64;
        open_edges += shared.values().filter(|&&n| n != 2).count() as u64;
        Ok(())
    })?;
    Ok(Written {
        vertices: count,
        triangles: nt,
        pieces: pieces(&mut parent),
        open_edges,
    })
}
