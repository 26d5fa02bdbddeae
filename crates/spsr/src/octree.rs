//! The adaptive, conforming octree (ALGORITHM.md §4).
//!
//! Layout. The unit cube `[0,1]^3` is embedded in a virtual root that covers `[-1,3]^3`, so
//! the tree depth `t` of a node is its unit-cube depth `d` plus [`DEPTH_OFFSET`]. This gives
//! every B-spline index just outside the cube (degree-1 functions at index `2^d`, free-boundary
//! degree-2 functions at `-1` and `2^d`) a real node, as PoissonRecon's virtual root does
//! (`_depthOffset`). Node creation is limited to the *ring* of unit offsets `-1..=2^d`:
//! no basis function lives farther out.
//!
//! Storage. Each tree depth is a [`Level`] whose nodes come in broods of 8 siblings stored
//! consecutively (node `8b + c` is child `c` of brood `b`, child bit 0 = x, 1 = y, 2 = z).
//! Broods are ordered by their parent, so every level is in Morton order. Each brood has
//! the 27 broods around it (the children of its parent's 3×3×3 neighbours), which gives any
//! node's 5×5×5 same-depth window in O(1) without hashing. Every level but the deepest stores
//! them (108 bytes a brood); the deepest level, the largest, derives them when asked from its
//! parent's row and child links ([`FromParent`]), which saves 13.5 bytes a node there.
//!
//! Invariants after [`Octree::build`]:
//! - levels with unit depth `≤ full_depth` contain every ring node;
//! - conforming (§4.2 step 5): if a node at unit depth `d ≥ base` has children, every node of
//!   the ring within its 5×5×5 window exists;
//! - the level of tree depth 0 is the virtual root alone; level 1 is its single brood.

use std::borrow::Cow;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use rayon::prelude::*;

use crate::shared_slice::split_into;

/// Tree depth of the unit cube.
pub const DEPTH_OFFSET: u32 = 2;

/// Marker for "no node / no brood".
pub const NONE: u32 = u32::MAX;

/// One depth of the tree.
///
/// Node keys are not stored per node: node `8b + c` of brood `b` has key
/// `2 · brood_key[b] + bits(c)`, which saves 12 bytes per node.
#[derive(Debug, Default, Clone)]
pub struct Level {
    /// Number of nodes (8 per brood; 1 for the virtual root's level).
    len: usize,
    /// Key (tree coordinates) of each brood's parent; empty at the root level.
    brood_key: Vec<[u32; 3]>,
    /// Brood index of each node's children at the next level, or [`NONE`]. Empty when no node
    /// of the level has children (the deepest level).
    child: Arc<[u32]>,
    /// Parent node (at the previous level) of each brood.
    pub brood_parent: Vec<u32>,
    /// The 27 broods around each brood ([`Level::brood_row`]); empty where they are derived.
    rows: Arc<[BroodRow]>,
    /// Where the rows are derived: the parent level's rows and child links.
    from_parent: Option<FromParent>,
    /// The broods whose rows hold a node with children ([`Level::row_has_children`]); empty
    /// at the deepest level.
    near_children: BroodSet,
}

/// The largest level's rows (the deepest's, usually: [`derives_rows`]) are not stored but
/// derived when asked from the parent level's rows and child links, which the level shares:
/// the children of the brood's parent's 3×3×3 neighbours (issue 20: at depth 10 the deepest
/// level's rows would be a fifth of the peak memory). A level below a deriving one stores its
/// rows, made from the derived ones.
#[derive(Debug, Clone)]
struct FromParent {
    rows: Arc<[BroodRow]>,
    child: Arc<[u32]>,
}

/// Window index ([`window_index`]) of each brood slot's offset `[-1,1]^3`.
const SLOT_WINDOW: [u8; 27] = {
    let mut w = [0u8; 27];
    let mut s = 0;
    while s < 27 {
        w[s] = ((s % 3 + 1) + 5 * ((s / 3) % 3 + 1) + 25 * (s / 9 + 1)) as u8;
        s += 1;
    }
    w
};

/// The 27 broods around a brood, slot `(dx+1) + 3(dy+1) + 9(dz+1)`, [`NONE`] if absent.
pub type BroodRow = [u32; 27];

/// A brood's row ([`Level::brood_row`]): the stored one, or one made for the asking.
pub enum RowRef<'a> {
    /// A level's stored row.
    Stored(&'a BroodRow),
    /// A row derived from the parent level's.
    Made(BroodRow),
}

impl std::ops::Deref for RowRef<'_> {
    type Target = BroodRow;
    #[inline]
    fn deref(&self) -> &BroodRow {
        match self {
            RowRef::Stored(row) => row,
            RowRef::Made(row) => row,
        }
    }
}

/// The row of the broods around the children of node `p` (at child position `p & 7`), from
/// the row `prow` of the broods around `p`'s brood and the level's `child` links: slot `s`
/// holds the children of `p`'s neighbour at the slot's offset.
#[inline]
fn row_of_children(prow: &[u32; 27], child: &[u32], p: u32) -> [u32; 27] {
    std::array::from_fn(|slot| slot_of_children(prow, child, p, slot))
}

/// Slot `slot` of [`row_of_children`] alone.
#[inline]
fn slot_of_children(prow: &[u32; 27], child: &[u32], p: u32, slot: usize) -> u32 {
    let c = (p & 7) as usize;
    let w = usize::from(SLOT_WINDOW[slot]);
    let pb = prow[usize::from(WINDOW.slot[c][w])];
    if pb == NONE {
        NONE
    } else {
        child[(pb * 8 + u32::from(WINDOW.bits[c][w])) as usize]
    }
}

impl Level {
    /// Number of nodes.
    #[inline]
    pub fn len(&self) -> usize {
        self.len
    }

    /// Integer offset of node `n` in tree coordinates (`0..2^t` per axis).
    #[inline]
    pub fn key(&self, n: u32) -> [u32; 3] {
        match self.brood_key.get((n >> 3) as usize) {
            Some(k) => [
                2 * k[0] + (n & 1),
                2 * k[1] + ((n >> 1) & 1),
                2 * k[2] + ((n >> 2) & 1),
            ],
            None => [0, 0, 0],
        }
    }

    /// The key of each brood's parent (empty at the root level).
    #[cfg(feature = "gpu")]
    pub fn brood_keys(&self) -> &[[u32; 3]] {
        &self.brood_key
    }

    /// Brood index of each node's children at the next level, or [`NONE`]; empty when no node
    /// has children (for the GPU's copy of [`Level::child`]).
    #[cfg(feature = "gpu")]
    pub fn children(&self) -> &[u32] {
        &self.child
    }

    /// Brood index of node `n`'s children at the next level, or [`NONE`].
    #[inline]
    pub fn child(&self, n: u32) -> u32 {
        self.child.get(n as usize).copied().unwrap_or(NONE)
    }

    /// Number of broods.
    #[inline]
    pub fn broods(&self) -> usize {
        self.brood_parent.len()
    }

    /// The 27 broods around brood `b` ([`BroodRow`]).
    #[inline(always)]
    pub fn brood_row(&self, b: u32) -> RowRef<'_> {
        match self.rows.get(b as usize) {
            Some(row) => RowRef::Stored(row),
            None => RowRef::Made(self.derived_row(b)),
        }
    }

    /// Whether some brood of brood `b`'s row ([`Level::brood_row`]) holds a node with
    /// children. When not, no node that the row reaches has children: whatever looks through
    /// the row at the next level (a finer depth's functions near a node, refined cells around
    /// a leaf) finds nothing there, and can stop before making the row. Where the samples
    /// hardly reach the deepest level, almost every brood of the level above it is such a
    /// brood (issue 20: spot_1m at depth 11).
    #[inline]
    pub fn row_has_children(&self, b: u32) -> bool {
        if self.near_children.is_empty() {
            return !self.child.is_empty();
        }
        self.near_children.contains(b)
    }

    /// How many broods [`Level::row_has_children`] accepts.
    pub fn broods_near_children(&self) -> usize {
        if self.near_children.is_empty() {
            return if self.child.is_empty() {
                0
            } else {
                self.len / 8
            };
        }
        self.near_children.len()
    }

    /// The broods whose rows ([`Level::brood_row`]) hold one of the nodes `nodes` (in
    /// increasing order). Rows are symmetric (brood `a` is in `b`'s row iff `b` is in `a`'s:
    /// their parents are neighbours), so each brood holding one of the nodes adds the broods of
    /// its own row.
    pub fn broods_reaching(&self, nodes: &[u32]) -> BroodSet {
        let words: Vec<AtomicU64> = (0..self.broods().div_ceil(64))
            .map(|_| AtomicU64::new(0))
            .collect();
        (0..nodes.len())
            .into_par_iter()
            .filter(|&i| i == 0 || nodes[i] >> 3 != nodes[i - 1] >> 3)
            .for_each(|i| {
                for &r in self.brood_row(nodes[i] >> 3).iter() {
                    if r != NONE {
                        words[(r / 64) as usize].fetch_or(1 << (r % 64), Ordering::Relaxed);
                    }
                }
            });
        BroodSet(words.into_iter().map(AtomicU64::into_inner).collect())
    }

    /// The brood in slot `slot` around brood `b` ([`Level::brood_row`]).
    #[inline(always)]
    pub fn brood_nbr(&self, b: u32, slot: usize) -> u32 {
        match self.rows.get(b as usize) {
            Some(row) => row[slot],
            None => self.derived_nbr(b, slot),
        }
    }

    /// [`Level::brood_row`] where it is derived.
    #[inline(never)]
    fn derived_row(&self, b: u32) -> BroodRow {
        match &self.from_parent {
            Some(from) => {
                let p = self.brood_parent[b as usize];
                row_of_children(&from.rows[(p >> 3) as usize], &from.child, p)
            }
            None => [NONE; 27],
        }
    }

    /// Slot `slot` of [`Level::derived_row`] alone.
    #[inline(never)]
    fn derived_nbr(&self, b: u32, slot: usize) -> u32 {
        let Some(from) = &self.from_parent else {
            return NONE;
        };
        let p = self.brood_parent[b as usize];
        slot_of_children(&from.rows[(p >> 3) as usize], &from.child, p, slot)
    }

    /// The row ([`Level::brood_row`]) of node `p`'s children at the next level.
    #[inline]
    fn children_row(&self, p: u32) -> [u32; 27] {
        row_of_children(&self.brood_row(p >> 3), &self.child, p)
    }

    /// Every brood's row ([`Level::brood_row`]): borrowed where stored, made (in parallel)
    /// where derived.
    pub fn brood_rows(&self) -> Cow<'_, [[u32; 27]]> {
        match &self.from_parent {
            None => Cow::Borrowed(&self.rows),
            Some(_) => Cow::Owned(
                (0..self.broods() as u32)
                    .into_par_iter()
                    .map(|b| self.derived_row(b))
                    .collect(),
            ),
        }
    }

    /// What [`Level::brood_rows`] is made from, as an address and a length, which stay the
    /// same while the tree lives (so that a copy of the rows elsewhere can be recognised).
    #[cfg(feature = "gpu")]
    pub fn brood_rows_identity(&self) -> (usize, usize) {
        match &self.from_parent {
            None => (self.rows.as_ptr() as usize, self.rows.len()),
            Some(from) => (from.rows.as_ptr() as usize + 1, self.broods()),
        }
    }
}

/// The octree: one [`Level`] per tree depth.
#[derive(Debug, Default, Clone)]
pub struct Octree {
    /// Levels by tree depth.
    pub levels: Vec<Level>,
}

/// Offset lookup table for same-level windows: for child position `c` and window offset
/// `δ ∈ [-2,2]^3` (index `(δx+2) + 5(δy+2) + 25(δz+2)`), the brood slot and the child bits.
pub struct WindowTable {
    slot: [[u8; 125]; 8],
    bits: [[u8; 125]; 8],
}

/// The window table, computed at compile time.
pub static WINDOW: WindowTable = {
    let mut slot = [[0u8; 125]; 8];
    let mut bits = [[0u8; 125]; 8];
    let mut c = 0;
    while c < 8 {
        let mut w = 0;
        while w < 125 {
            let d = [
                (w % 5) as i32 - 2,
                ((w / 5) % 5) as i32 - 2,
                (w / 25) as i32 - 2,
            ];
            let mut s = 0usize;
            let mut b = 0u8;
            let mut mul = 1usize;
            let mut a = 0;
            while a < 3 {
                let cb = ((c >> a) & 1) as i32;
                let v = cb + d[a] + 2; // 0..=5
                s += (v as usize >> 1) * mul;
                b |= ((v & 1) as u8) << a;
                mul *= 3;
                a += 1;
            }
            slot[c][w] = s as u8;
            bits[c][w] = b;
            w += 1;
        }
        c += 1;
    }
    WindowTable { slot, bits }
};

/// The same-depth offset, from a node at child position `c`, of node `k` of the brood in
/// neighbour slot `slot` (`(dx+1) + 3(dy+1) + 9(dz+1)`, as [`Level::brood_row`]).
#[inline]
pub fn brood_offset(c: usize, slot: u8, k: usize) -> [i64; 3] {
    let db = [slot % 3, slot / 3 % 3, slot / 9].map(|v| i64::from(v) - 1);
    std::array::from_fn(|a| 2 * db[a] + ((k >> a) & 1) as i64 - ((c >> a) & 1) as i64)
}

#[cfg(feature = "gpu")]
impl WindowTable {
    /// The brood slot (of the 27 around a brood) of each child position and window offset.
    pub fn slots(&self) -> &[[u8; 125]; 8] {
        &self.slot
    }

    /// The child bits within that brood, laid out as [`WindowTable::slots`].
    pub fn child_bits(&self) -> &[[u8; 125]; 8] {
        &self.bits
    }
}

/// Window index of an offset in `[-2,2]^3`.
#[inline]
pub fn window_index(d: [i64; 3]) -> usize {
    ((d[0] + 2) + 5 * (d[1] + 2) + 25 * (d[2] + 2)) as usize
}

/// Range of ring offsets (tree coordinates, inclusive) at tree depth `t`.
pub fn ring(t: u32) -> (i64, i64) {
    if t < DEPTH_OFFSET {
        (0, (1i64 << t) - 1)
    } else {
        let n = 1i64 << (t - DEPTH_OFFSET);
        (n - 1, 2 * n)
    }
}

#[inline]
fn pack(k: [i64; 3]) -> u64 {
    (k[0] as u64) | ((k[1] as u64) << 21) | ((k[2] as u64) << 42)
}

/// The key of a packed key (as [`ClosedRequest::refined_keys`] gives them).
#[inline]
pub(crate) fn unpack(p: u64) -> [u32; 3] {
    let m = (1u64 << 21) - 1;
    [
        (p & m) as u32,
        ((p >> 21) & m) as u32,
        ((p >> 42) & m) as u32,
    ]
}

/// Interleaves the bits of a key (x lowest) into a Morton code.
#[cfg(test)]
fn morton(k: [u32; 3]) -> u64 {
    crate::morton::encode(k.map(u64::from))
}

/// Requests gathered before building: nodes that must have children, by tree depth.
#[derive(Debug, Default)]
pub struct TreeRequest {
    /// `refined[t]`: Morton codes of the nodes at tree depth `t` that must have children, in
    /// any order and with repeats until [`TreeRequest::close`] sorts them. Sorted lists, unlike
    /// a hash set, can be built by threads in parts and joined, and sorted by code they are
    /// already in the order of the levels' nodes.
    refined: Vec<Vec<u64>>,
}

/// Items per piece of work in the parallel passes over keys and codes.
const CHUNK: usize = 1 << 14;

/// The Morton code of a key.
#[inline]
fn code(k: [i64; 3]) -> u64 {
    crate::morton::encode(k.map(|c| c as u64))
}

/// The key of a Morton code.
#[inline]
fn key_of(m: u64) -> [u32; 3] {
    crate::morton::decode(m).map(|c| c as u32)
}

/// Sorts `v` and drops repeats: a set as a sorted list. `par_sort` (a merge sort) is fast on
/// the concatenated sorted runs that the passes below produce.
fn sort_set(v: &mut Vec<u64>) {
    v.par_sort();
    *v = dedup_sorted(v);
}

/// The distinct values of the sorted `v`, in order: each run of values keeps its first,
/// found in parallel pieces and joined.
fn dedup_sorted(v: &[u64]) -> Vec<u64> {
    let parts = v
        .par_chunks(CHUNK)
        .enumerate()
        .map(|(i, chunk)| {
            let before = (i * CHUNK).checked_sub(1).map(|j| v[j]);
            let mut out = Vec::with_capacity(chunk.len());
            for &x in chunk {
                if out.last().or(before.as_ref()) != Some(&x) {
                    out.push(x);
                }
            }
            out
        })
        .collect();
    concat(parts)
}

/// Joins sorted lists, in order, into one vector (the pieces of a parallel pass).
fn concat<T: Copy + Default + Send + Sync>(parts: Vec<Vec<T>>) -> Vec<T> {
    let mut all = Vec::new();
    all.par_extend(rayon::iter::repeat_n(
        T::default(),
        parts.iter().map(Vec::len).sum(),
    ));
    split_into(&mut all, parts.iter().map(Vec::len))
        .into_par_iter()
        .zip(&parts)
        .for_each(|(slot, p)| slot.copy_from_slice(p));
    all
}

impl TreeRequest {
    /// An empty request for a tree of maximal tree depth `max_t`.
    pub fn new(max_t: u32) -> Self {
        Self {
            refined: vec![Vec::new(); max_t as usize + 1],
        }
    }

    /// Requires the `(2r+1)^3` window of nodes around `k` at tree depth `t` (clipped to the ring).
    pub fn require_window(&mut self, t: u32, k: [i64; 3], r: i64) {
        if t == 0 {
            return;
        }
        let (lo, hi) = ring(t);
        let lo3: [i64; 3] = std::array::from_fn(|a| ((k[a] - r).max(lo)) >> 1);
        let hi3: [i64; 3] = std::array::from_fn(|a| ((k[a] + r).min(hi)) >> 1);
        let set = &mut self.refined[t as usize - 1];
        for z in lo3[2]..=hi3[2] {
            for y in lo3[1]..=hi3[1] {
                for x in lo3[0]..=hi3[0] {
                    set.push(code([x, y, z]));
                }
            }
        }
    }

    /// Sorts each depth's codes and drops repeats, so that a request made over part of the
    /// samples is small before [`TreeRequest::union`] joins it with the others.
    pub fn compact(&mut self) {
        for level in &mut self.refined {
            level.sort_unstable();
            level.dedup();
        }
    }

    /// One request holding every node of `parts` (requests made in parallel over parts of the
    /// samples), for a tree of maximal tree depth `max_t`.
    pub fn union(parts: Vec<TreeRequest>, max_t: u32) -> TreeRequest {
        let mut refined: Vec<Vec<Vec<u64>>> = vec![Vec::new(); max_t as usize + 1];
        for part in parts {
            for (all, level) in refined.iter_mut().zip(part.refined) {
                all.push(level);
            }
        }
        let refined = refined
            .into_par_iter()
            .map(|parts| {
                let mut level = concat(parts);
                sort_set(&mut level);
                level
            })
            .collect();
        TreeRequest { refined }
    }
}

/// A request closed under completeness, ancestry and the conforming rule: its node count is
/// known before any level is built.
#[derive(Debug)]
pub struct ClosedRequest(TreeRequest);

impl ClosedRequest {
    /// Number of nodes the tree will have at each tree depth.
    pub fn level_counts(&self) -> Vec<usize> {
        std::iter::once(1)
            .chain(self.0.refined.iter().map(|r| 8 * r.len()))
            .take(self.0.refined.len())
            .collect()
    }
}

impl ClosedRequest {
    /// The keys (packed) of the nodes at tree depth `t` that have children, sorted: with
    /// [`TreeRequest::refine_keys`], how slabs gather the coarse levels of one tree from the
    /// closed requests of their samples (closing distributes over the union of requests).
    pub fn refined_keys(&self, t: u32) -> Vec<u64> {
        let mut keys: Vec<u64> = self.0.refined.get(t as usize).map_or_else(Vec::new, |s| {
            s.par_iter().map(|&m| pack_u(key_of(m))).collect()
        });
        keys.par_sort_unstable();
        keys
    }
}

/// The Morton codes of every ring node at tree depth `t`.
fn ring_codes(t: u32) -> Vec<u64> {
    let (lo, hi) = ring(t);
    (lo..=hi)
        .into_par_iter()
        .flat_map_iter(|z| (lo..=hi).flat_map(move |y| (lo..=hi).map(move |x| code([x, y, z]))))
        .collect()
}

/// The nodes one depth up that must have children because the nodes `refined` (sorted codes)
/// do: their parents, and with `ring` (the ring of the parents' depth, for the conforming
/// rule) the ring nodes among the parents' 3×3×3 neighbours. Sorted runs, with repeats.
fn required_above(refined: &[u64], ring: Option<(i64, i64)>) -> Vec<u64> {
    let parts = refined
        .par_chunks(CHUNK)
        .map(|chunk| {
            let mut up: Vec<u64> = chunk.iter().map(|&m| m >> 3).collect();
            up.dedup();
            if let Some((lo, hi)) = ring {
                up = up.iter().flat_map(|&p| neighbours_in(p, lo, hi)).collect();
                up.sort_unstable();
                up.dedup();
            }
            up
        })
        .collect();
    concat(parts)
}

/// The codes of the nodes in the 3×3×3 window around the node of code `p` whose every
/// coordinate lies in `lo..=hi`.
fn neighbours_in(p: u64, lo: i64, hi: i64) -> impl Iterator<Item = u64> {
    let k = key_of(p).map(i64::from);
    let axis = move |a: usize| (k[a] - 1).max(lo)..=(k[a] + 1).min(hi);
    axis(2).flat_map(move |z| axis(1).flat_map(move |y| axis(0).map(move |x| code([x, y, z]))))
}

impl TreeRequest {
    /// Requires the nodes with packed keys `keys` at tree depth `t` to have children.
    pub fn refine_keys(&mut self, t: u32, keys: impl IntoIterator<Item = u64>) {
        if let Some(set) = self.refined.get_mut(t as usize) {
            set.extend(keys.into_iter().map(|p| code(unpack(p).map(i64::from))));
        }
    }

    /// Makes levels of unit depth `≤ full_depth` complete, closes the request under ancestry,
    /// and enforces the conforming property at unit depths `≥ conform_from` (ALGORITHM.md §4.2
    /// steps 3 and 5).
    pub fn close(mut self, full_depth: u32, conform_from: u32) -> ClosedRequest {
        let max_t = self.refined.len() as u32 - 1;
        // Complete levels: every ring node at unit depth < full_depth has children.
        for t in 0..(full_depth + DEPTH_OFFSET).min(max_t) {
            let level = &mut self.refined[t as usize];
            *level = concat(vec![std::mem::take(level), ring_codes(t)]);
        }
        self.refined.iter_mut().for_each(sort_set);
        // Fine to coarse: every refined node needs its parent refined; with conforming, the
        // 5×5×5 window around a refined node must exist, which means the 3×3×3 parents around
        // its parent must be refined.
        for t in (1..max_t).rev() {
            let conform = t >= conform_from + DEPTH_OFFSET;
            let up = required_above(&self.refined[t as usize], conform.then(|| ring(t - 1)));
            let level = &mut self.refined[t as usize - 1];
            *level = concat(vec![std::mem::take(level), up]);
            sort_set(level);
        }
        // The root always exists and has children.
        let root = &mut self.refined[0];
        if root.first() != Some(&0) {
            root.insert(0, 0);
        }
        ClosedRequest(self)
    }
}

/// The nodes of a level that have children, and their codes: the codes `refined` (sorted)
/// that are nodes of the level whose broods' parents have the sorted codes `broods` (a node's
/// code is its brood's parent's code and its child bits). Codes of no node are skipped.
fn locate(refined: &[u64], broods: &[u64]) -> (Vec<u32>, Vec<u64>) {
    let parts: Vec<(Vec<u32>, Vec<u64>)> = refined
        .par_chunks(CHUNK)
        .map(|chunk| {
            let mut b = broods.partition_point(|&c| c < chunk[0] >> 3);
            let mut out = (
                Vec::with_capacity(chunk.len()),
                Vec::with_capacity(chunk.len()),
            );
            for &m in chunk {
                while b < broods.len() && broods[b] < m >> 3 {
                    b += 1;
                }
                if broods.get(b) == Some(&(m >> 3)) {
                    out.0.push(8 * b as u32 + (m & 7) as u32);
                    out.1.push(m);
                }
            }
            out
        })
        .collect();
    let (nodes, codes): (Vec<_>, Vec<_>) = parts.into_iter().unzip();
    rayon::join(|| concat(nodes), || concat(codes))
}

/// The child array of a level of `len` nodes whose nodes `parents` (increasing) have the
/// broods `0, 1, …` of the next level: filled in blocks of nodes, in parallel.
fn child_array(len: usize, parents: &[u32]) -> Arc<[u32]> {
    let mut child = Arc::<[u32]>::new_uninit_slice(len);
    let block_of = Arc::get_mut(&mut child).expect("a new slice has one owner");
    block_of
        .par_chunks_mut(CHUNK)
        .enumerate()
        .for_each(|(i, block)| {
            let lo = (i * CHUNK) as u32;
            for c in block.iter_mut() {
                c.write(NONE);
            }
            let first = parents.partition_point(|&p| p < lo);
            for (b, &p) in parents.iter().enumerate().skip(first) {
                match block.get_mut((p - lo) as usize) {
                    Some(c) => {
                        c.write(b as u32);
                    }
                    None => break,
                }
            }
        });
    // SAFETY: every element was written above (each chunk's elements first set to NONE).
    unsafe { child.assume_init() }
}

/// Whether a level of `broods` broods, whose next level has `next_broods` (0: it is the
/// deepest), derives its rows rather than storing them ([`FromParent`]): the deepest level
/// does, and so does a level whose next level is under a quarter of its size. Each level is
/// usually two to three times the one above it, so that is the deepest; but where the
/// samples hardly reach the requested depth, the level above it is the largest (spot_1m at
/// depth 11: 8.3 million nodes at depth 10, 1,792 at depth 11), and storing its rows cost 112
/// MB of a 776 MiB peak (issue 20).
fn derives_rows(broods: usize, next_broods: usize) -> bool {
    next_broods == 0 || 4 * next_broods < broods
}

/// The 27 broods around each brood of a new level whose broods' parents are `parents` in
/// `prev` (whose child array is set).
/// Made in place in the shared slice: collecting into a `Vec` first and converting it would
/// copy the rows (67 MB at depth 9 of a million points; issue 20).
fn brood_neighbours(prev: &Level, parents: &[u32]) -> Arc<[[u32; 27]]> {
    let mut rows = Arc::<[[u32; 27]]>::new_uninit_slice(parents.len());
    Arc::get_mut(&mut rows)
        .expect("a new slice has one owner")
        .par_iter_mut()
        .zip(parents.par_iter())
        .for_each(|(row, &p)| {
            row.write(prev.children_row(p));
        });
    // SAFETY: every row was written above (one per parent).
    unsafe { rows.assume_init() }
}

/// A set of a level's broods, one bit each ([`Level::broods_reaching`]).
#[derive(Debug, Default, Clone)]
pub struct BroodSet(Vec<u64>);

impl BroodSet {
    /// Whether brood `b` is in the set.
    #[inline]
    pub fn contains(&self, b: u32) -> bool {
        self.0
            .get((b / 64) as usize)
            .is_some_and(|w| w >> (b % 64) & 1 != 0)
    }

    fn is_empty(&self) -> bool {
        self.0.is_empty()
    }

    /// Number of broods in the set.
    fn len(&self) -> usize {
        self.0.iter().map(|w| w.count_ones() as usize).sum()
    }
}

impl Octree {
    /// Builds the tree from the requested nodes: makes levels of unit depth `≤ full_depth`
    /// complete, closes the request under ancestry, and enforces the conforming property at
    /// unit depths `≥ conform_from` (ALGORITHM.md §4.2 steps 3 and 5).
    #[cfg(test)]
    pub fn build(req: TreeRequest, full_depth: u32, conform_from: u32) -> Octree {
        Octree::materialize(req.close(full_depth, conform_from))
    }

    /// Builds the levels of a closed request (see [`TreeRequest::close`]), top-down; each
    /// level's broods are its refined codes that are nodes, in code (Morton) order.
    pub fn materialize(req: ClosedRequest) -> Octree {
        let req = req.0;
        let max_t = req.refined.len() as u32 - 1;
        let mut levels: Vec<Level> = Vec::with_capacity(max_t as usize + 1);
        levels.push(Level {
            len: 1,
            ..Level::default()
        });
        // Each level's broods are located one level ahead, so that the deepest level is known
        // before its rows would be made.
        let root = req.refined[0].binary_search(&0).is_ok();
        let mut located = if root {
            (vec![0], vec![0])
        } else {
            (vec![], vec![])
        };
        for t in 1..=max_t {
            let (parents, codes) = std::mem::take(&mut located);
            if parents.is_empty() {
                break;
            }
            if t < max_t {
                located = locate(&req.refined[t as usize], &codes);
            }
            let derives = derives_rows(parents.len(), located.0.len());
            let prev = &mut levels[t as usize - 1];
            prev.child = child_array(prev.len, &parents);
            let prev = &levels[t as usize - 1];
            // Level 1 holds the root's one brood, alone; the largest level derives its rows
            // ([`derives_rows`]) where its parent level stores its own.
            let (rows, from_parent): (Arc<[BroodRow]>, _) = if t == 1 {
                let mut row = [NONE; 27];
                row[13] = 0;
                (Arc::from(vec![row]), None)
            } else if derives && prev.from_parent.is_none() {
                let from = FromParent {
                    rows: prev.rows.clone(),
                    child: prev.child.clone(),
                };
                (Arc::from(Vec::new()), Some(from))
            } else {
                (brood_neighbours(prev, &parents), None)
            };
            let brood_key: Vec<[u32; 3]> = codes.par_iter().map(|&m| key_of(m)).collect();
            levels.push(Level {
                len: brood_key.len() * 8,
                brood_key,
                child: Arc::from(Vec::new()),
                brood_parent: parents,
                rows,
                from_parent,
                near_children: BroodSet::default(),
            });
        }
        for t in 1..levels.len().saturating_sub(1) {
            let near = levels[t].broods_reaching(&levels[t + 1].brood_parent);
            levels[t].near_children = near;
        }
        Octree { levels }
    }

    /// Number of tree levels.
    pub fn depth_count(&self) -> u32 {
        self.levels.len() as u32
    }

    /// The same-level neighbour of node `n` at tree depth `t ≥ 1` by offset `d ∈ [-2,2]^3`.
    #[inline]
    pub fn neighbor(&self, t: u32, n: u32, d: [i64; 3]) -> u32 {
        neighbor_in(&self.levels[t as usize], n, window_index(d))
    }

    /// The parent of node `n` at tree depth `t ≥ 1`.
    #[inline]
    pub fn parent(&self, t: u32, n: u32) -> u32 {
        self.levels[t as usize].brood_parent[(n / 8) as usize]
    }

    /// Deepest node containing the tree-coordinate point `key` given at tree depth `t_key`,
    /// descending at most to tree depth `t_max`. Returns `(tree depth, node)`.
    pub fn descend(&self, key: [u64; 3], t_key: u32, t_max: u32) -> (u32, u32) {
        self.descend_from(key, t_key, t_max, (0, 0))
    }

    /// [`Octree::descend`] to tree depth `t_key`, starting from the node at `near`'s depth
    /// that contains `key` when it is one of `near`'s same-depth neighbours (the deepest node
    /// is the same: that node lies on the path from the root). A point on or near a leaf's
    /// closure so skips the walk down from the root.
    pub fn descend_near(&self, key: [u64; 3], t_key: u32, (t, n): (u32, u32)) -> (u32, u32) {
        let level = &self.levels[t as usize];
        let own = level.key(n);
        let shift = t_key - t;
        let rel: [i64; 3] = std::array::from_fn(|a| (key[a] >> shift) as i64 - i64::from(own[a]));
        if rel.iter().all(|r| (-2..=2).contains(r)) {
            let m = neighbor_in(level, n, window_index(rel));
            if m != NONE {
                return self.descend_from(key, t_key, t_key, (t, m));
            }
        }
        self.descend(key, t_key, t_key)
    }

    /// [`Octree::descend`] from node `n` at tree depth `t`, which contains `key`.
    fn descend_from(
        &self,
        key: [u64; 3],
        t_key: u32,
        t_max: u32,
        (t, n): (u32, u32),
    ) -> (u32, u32) {
        let (mut t, mut n) = (t, n);
        while t < t_max && (t as usize + 1) < self.levels.len() {
            let b = self.levels[t as usize].child(n);
            if b == NONE {
                break;
            }
            let shift = t_key - (t + 1);
            let c = ((key[0] >> shift) & 1)
                | (((key[1] >> shift) & 1) << 1)
                | (((key[2] >> shift) & 1) << 2);
            n = b * 8 + c as u32;
            t += 1;
        }
        (t, n)
    }
}

#[inline]
fn pack_u(k: [u32; 3]) -> u64 {
    pack([i64::from(k[0]), i64::from(k[1]), i64::from(k[2])])
}

/// Same-level neighbour of node `n` by window index `w` (see [`window_index`]).
#[inline(always)]
pub fn neighbor_in(level: &Level, n: u32, w: usize) -> u32 {
    let c = (n & 7) as usize;
    let b = level.brood_nbr(n >> 3, usize::from(WINDOW.slot[c][w]));
    if b == NONE {
        NONE
    } else {
        b * 8 + u32::from(WINDOW.bits[c][w])
    }
}

/// [`neighbor_in`] from the row of node `n`'s brood ([`Level::brood_row`]).
#[inline]
pub fn neighbor_in_row(row: &BroodRow, n: u32, w: usize) -> u32 {
    let c = (n & 7) as usize;
    let b = row[usize::from(WINDOW.slot[c][w])];
    if b == NONE {
        NONE
    } else {
        b * 8 + u32::from(WINDOW.bits[c][w])
    }
}

/// `f(n, row)` for every node `n` of a level of broods, with the row of its brood
/// ([`Level::brood_row`], made once per brood), in parallel; the results in node order.
pub fn map_nodes<T: Send>(level: &Level, f: impl Fn(u32, &BroodRow) -> T + Sync) -> Vec<T> {
    (0..level.broods() as u32)
        .into_par_iter()
        .map(|b| {
            let row = level.brood_row(b);
            std::array::from_fn::<T, 8, _>(|k| f(8 * b + k as u32, &row))
        })
        .collect::<Vec<[T; 8]>>()
        .into_flattened()
}

/// `f(n, row, item)` for every node `n` of a level of broods and its item (`items` holds one
/// per node), with the row of its brood (made once per brood), in parallel.
pub fn for_each_node<T: Send>(
    level: &Level,
    items: &mut [T],
    f: impl Fn(u32, &BroodRow, &mut T) + Sync,
) {
    items.par_chunks_mut(8).enumerate().for_each(|(b, brood)| {
        let row = level.brood_row(b as u32);
        for (k, item) in brood.iter_mut().enumerate() {
            f(8 * b as u32 + k as u32, &row, item);
        }
    });
}

/// Function index (unit offset) of a tree key at unit depth `d`.
#[inline]
pub fn func_index(key: [u32; 3], d: u32) -> [i64; 3] {
    let n = 1i64 << d;
    [
        i64::from(key[0]) - n,
        i64::from(key[1]) - n,
        i64::from(key[2]) - n,
    ]
}

/// The rank of each member of a set of node indices (a bitmap with a running count per 64
/// nodes: 1.5 bits per node instead of a 32-bit index per node).
#[derive(Debug, Default, Clone)]
pub struct NodeRank {
    bits: Vec<u64>,
    before: Vec<u32>,
}

impl NodeRank {
    /// The bitmap of members (bit `m & 63` of word `m >> 6`) and the members before each word.
    #[cfg(feature = "gpu")]
    pub fn words(&self) -> (&[u64], &[u32]) {
        (&self.bits, &self.before)
    }

    /// The set of `members` (strictly increasing) among `len` nodes; member `k` has rank `k`.
    pub fn new(len: usize, members: impl Iterator<Item = u32>) -> Self {
        let words = len.div_ceil(64);
        let mut bits = vec![0u64; words];
        for m in members {
            bits[(m >> 6) as usize] |= 1 << (m & 63);
        }
        let mut before = Vec::with_capacity(words);
        let mut count = 0u32;
        for w in &bits {
            before.push(count);
            count += w.count_ones();
        }
        Self { bits, before }
    }

    /// The members among brood `b`'s eight nodes (bit `k` for node `8b + k`) and the rank
    /// of the first member: node `8b + k`'s rank is the second plus the members below bit `k`.
    #[inline]
    pub fn brood(&self, b: u32) -> (u8, u32) {
        let k = (b >> 3) as usize;
        let Some(&word) = self.bits.get(k) else {
            return (0, 0);
        };
        let shift = (b & 7) * 8;
        let members = (word >> shift) as u8;
        if members == 0 {
            return (0, 0);
        }
        (
            members,
            self.before[k] + (word & ((1u64 << shift) - 1)).count_ones(),
        )
    }

    /// Rank of node `m`, or [`NONE`] if it is not a member.
    #[inline]
    pub fn get(&self, m: u32) -> u32 {
        let k = (m >> 6) as usize;
        let Some(&word) = self.bits.get(k) else {
            return NONE;
        };
        let bit = 1u64 << (m & 63);
        if word & bit == 0 {
            return NONE;
        }
        self.before[k] + (word & (bit - 1)).count_ones()
    }
}

#[cfg(test)]
impl Octree {
    /// A test tree whose deepest depths the samples hardly reach: depth 4 complete (4096
    /// nodes) and, below it, the conforming closure of one node refined to depth 6, so that
    /// depths 5 and 6 are far smaller than depth 4.
    pub(crate) fn full_depth_4_and_one_path_to_6() -> Octree {
        let max_t = 6 + DEPTH_OFFSET;
        let mut req = TreeRequest::new(max_t);
        req.require_window(max_t, [64 + 20, 64 + 40, 64 + 30], 1);
        Octree::build(req, 4, 4)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rustc_hash::FxHashSet;

    fn splitmix(s: &mut u64) -> u64 {
        *s = s.wrapping_add(0x9e37_79b9_7f4a_7c15);
        let mut z = *s;
        z = (z ^ (z >> 30)).wrapping_mul(0xbf58_476d_1ce4_e5b9);
        z = (z ^ (z >> 27)).wrapping_mul(0x94d0_49bb_1331_11eb);
        z ^ (z >> 31)
    }

    #[test]
    fn morton_interleaves_bits() {
        assert_eq!(morton([1, 0, 0]), 1);
        assert_eq!(morton([0, 1, 0]), 2);
        assert_eq!(morton([0, 0, 1]), 4);
        assert_eq!(morton([3, 0, 0]), 0b1001);
        assert_eq!(morton([0x1f_ffff, 0, 0]) >> 60, 1);
        let mut s = 7;
        for _ in 0..1000 {
            let k = [
                (splitmix(&mut s) & 0xfffff) as u32,
                (splitmix(&mut s) & 0xfffff) as u32,
                (splitmix(&mut s) & 0xfffff) as u32,
            ];
            let m = morton(k);
            let mut back = [0u32; 3];
            for bit in 0..21 {
                for (a, b) in back.iter_mut().enumerate() {
                    *b |= (((m >> (3 * bit + a)) & 1) as u32) << bit;
                }
            }
            assert_eq!(back, k);
        }
    }

    fn random_tree(seed: u64, full: u32, max_d: u32) -> Octree {
        let max_t = max_d + DEPTH_OFFSET;
        let mut req = TreeRequest::new(max_t);
        let mut s = seed;
        for _ in 0..40 {
            let d = full + 1 + (splitmix(&mut s) % u64::from(max_d - full)) as u32;
            let n = 1u64 << d;
            let k: [i64; 3] = std::array::from_fn(|_| (splitmix(&mut s) % n) as i64 + n as i64);
            req.require_window(d + DEPTH_OFFSET, k, 1);
        }
        Octree::build(req, full, full)
    }

    #[test]
    fn levels_are_complete_to_full_depth() {
        let tree = random_tree(1, 3, 6);
        for d in 0..=3u32 {
            let t = d + DEPTH_OFFSET;
            let (lo, hi) = ring(t);
            let level = &tree.levels[t as usize];
            let keys: FxHashSet<u64> = (0..level.len() as u32)
                .map(|n| pack_u(level.key(n)))
                .collect();
            for z in lo..=hi {
                for y in lo..=hi {
                    for x in lo..=hi {
                        assert!(
                            keys.contains(&pack([x, y, z])),
                            "missing ring node at depth {d}"
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn tree_is_conforming_and_neighbours_are_right() {
        for seed in 0..4 {
            let tree = random_tree(seed, 2, 7);
            for t in 1..tree.depth_count() {
                let level = &tree.levels[t as usize];
                let index: rustc_hash::FxHashMap<u64, u32> = (0..level.len() as u32)
                    .map(|n| (pack_u(level.key(n)), n))
                    .collect();
                let (lo, hi) = ring(t);
                for n in 0..level.len() {
                    let k = level.key(n as u32);
                    // Children keys are consistent.
                    if level.child(n as u32) != NONE {
                        let next = &tree.levels[t as usize + 1];
                        for c in 0..8u32 {
                            let ck = next.key(level.child(n as u32) * 8 + c);
                            assert_eq!(ck[0], 2 * k[0] + (c & 1));
                            assert_eq!(ck[2], 2 * k[2] + (c >> 2));
                        }
                    }
                    // Neighbour lookups agree with a hash lookup.
                    for w in 0..125 {
                        let d = [
                            (w % 5) as i64 - 2,
                            ((w / 5) % 5) as i64 - 2,
                            (w / 25) as i64 - 2,
                        ];
                        let q = [k[0] as i64 + d[0], k[1] as i64 + d[1], k[2] as i64 + d[2]];
                        let expect = if q.iter().all(|&c| c >= 0 && c < (1 << t)) {
                            index.get(&pack(q)).copied().unwrap_or(NONE)
                        } else {
                            NONE
                        };
                        assert_eq!(tree.neighbor(t, n as u32, d), expect);
                        let row = level.brood_row(n as u32 >> 3);
                        assert_eq!(neighbor_in_row(&row, n as u32, w), expect);
                        // Conforming: around a refined node at unit depth >= 2, the ring window exists.
                        if level.child(n as u32) != NONE
                            && t >= 2 + DEPTH_OFFSET
                            && q.iter().all(|&c| c >= lo && c <= hi)
                        {
                            assert_ne!(expect, NONE, "conforming window broken at t={t}");
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn a_level_derives_its_rows_where_the_next_is_small_or_absent() {
        for seed in 0..4 {
            let tree = random_tree(seed, 2, 6);
            let mut parent_derived = false;
            for (t, level) in tree.levels.iter().enumerate().skip(1) {
                let next = tree.levels.get(t + 1).map_or(0, Level::broods);
                let derived = t > 1 && !parent_derived && derives_rows(level.broods(), next);
                assert_eq!(level.from_parent.is_some(), derived, "level {t}");
                assert_eq!(level.rows.is_empty(), derived, "level {t}");
                parent_derived = derived;
            }
            assert_rows_agree(&tree);
        }
    }

    #[test]
    fn a_level_much_larger_than_the_next_derives_its_rows_and_the_next_stores_them() {
        let tree = Octree::full_depth_4_and_one_path_to_6();
        let t4 = (4 + DEPTH_OFFSET) as usize;
        assert!(4 * tree.levels[t4 + 1].len() < tree.levels[t4].len());
        for (t, level) in tree.levels.iter().enumerate().skip(1) {
            let derived = t == t4 || t == tree.levels.len() - 1;
            assert_eq!(level.from_parent.is_some(), derived, "level {t}");
            assert_eq!(level.rows.is_empty(), derived, "level {t}");
        }
        assert_rows_agree(&tree);
        // The rows, stored or derived, are those of the neighbour search: slot `s` holds the
        // brood whose first node is two nodes along `s` from the brood's first node.
        for (t, level) in tree.levels.iter().enumerate().skip(2) {
            for b in 0..level.broods() as u32 {
                for (slot, &nb) in level.brood_row(b).iter().enumerate() {
                    let d = [slot % 3, slot / 3 % 3, slot / 9].map(|v| 2 * (v as i64 - 1));
                    let m = tree.neighbor(t as u32, 8 * b, d);
                    let want = if nb == NONE { NONE } else { 8 * nb };
                    assert_eq!(m, want, "level {t} brood {b} slot {slot}");
                }
            }
        }
    }

    #[test]
    fn a_brood_row_has_children_iff_one_of_its_broods_holds_a_refined_node() {
        let mut trees: Vec<Octree> = (0..3).map(|seed| random_tree(seed, 2, 6)).collect();
        // A level far larger than the next (the case the flags are for).
        trees.push(Octree::full_depth_4_and_one_path_to_6());
        for tree in &trees {
            let last = tree.levels.len() - 1;
            let mut some_without = false;
            for (t, level) in tree.levels.iter().enumerate().skip(1) {
                for b in 0..level.broods() as u32 {
                    let want = t < last
                        && level
                            .brood_row(b)
                            .iter()
                            .any(|&r| r != NONE && (0..8).any(|k| level.child(8 * r + k) != NONE));
                    assert_eq!(level.row_has_children(b), want, "level {t} brood {b}");
                    some_without |= t < last && !want;
                }
            }
            assert!(
                some_without,
                "every brood of the tree is near a refined node"
            );
        }
    }

    #[test]
    fn the_broods_reaching_some_nodes_are_those_whose_rows_hold_one() {
        let tree = random_tree(7, 2, 6);
        let mut s = 11u64;
        for (t, level) in tree.levels.iter().enumerate().skip(2) {
            let mut nodes: Vec<u32> = (0..level.len() as u32)
                .filter(|_| splitmix(&mut s).is_multiple_of(16))
                .collect();
            nodes.dedup();
            let set = level.broods_reaching(&nodes);
            for b in 0..level.broods() as u32 {
                let want = level
                    .brood_row(b)
                    .iter()
                    .any(|&r| r != NONE && nodes.iter().any(|&n| n >> 3 == r));
                assert_eq!(set.contains(b), want, "level {t} brood {b}");
            }
        }
    }

    /// Every level's rows agree between [`Level::brood_rows`], [`Level::brood_row`] and
    /// [`Level::brood_nbr`].
    fn assert_rows_agree(tree: &Octree) {
        for level in tree.levels.iter().skip(1) {
            let rows = level.brood_rows();
            assert_eq!(rows.len(), level.broods());
            for (b, row) in rows.iter().enumerate() {
                assert_eq!(*row, *level.brood_row(b as u32));
                for (slot, &nb) in row.iter().enumerate() {
                    assert_eq!(level.brood_nbr(b as u32, slot), nb);
                }
            }
        }
    }

    #[test]
    fn parallel_set_helpers_agree_with_serial_ones() {
        // Runs of equal values that cross the pieces' boundaries.
        let v: Vec<u64> = (0..3 * CHUNK as u64 + 5).map(|i| i / 3).collect();
        let mut serial = v.clone();
        serial.dedup();
        assert_eq!(dedup_sorted(&v), serial);
        assert_eq!(concat(vec![vec![1u64, 2], vec![], vec![3]]), vec![1, 2, 3]);
        let len = 3 * CHUNK + 7;
        let parents: Vec<u32> = (0..len as u32).filter(|n| n % 5 == 0).collect();
        let child = child_array(len, &parents);
        for (n, &c) in child.iter().enumerate() {
            let expect = parents
                .binary_search(&(n as u32))
                .map_or(NONE, |b| b as u32);
            assert_eq!(c, expect);
        }
    }

    #[test]
    fn levels_are_in_morton_order() {
        let tree = random_tree(9, 2, 6);
        for level in &tree.levels {
            let m: Vec<u64> = (0..level.len() as u32)
                .map(|n| morton(level.key(n)))
                .collect();
            assert!(m.windows(2).all(|w| w[0] < w[1]));
        }
    }

    #[test]
    fn descend_finds_the_containing_leaf() {
        let tree = random_tree(3, 2, 6);
        let t_key = tree.depth_count() - 1;
        let mut s = 11;
        for _ in 0..500 {
            let n = 1u64 << (t_key - DEPTH_OFFSET);
            let key: [u64; 3] = std::array::from_fn(|_| splitmix(&mut s) % n + n);
            let (t, node) = tree.descend(key, t_key, t_key);
            let k = tree.levels[t as usize].key(node);
            for a in 0..3 {
                assert_eq!(u64::from(k[a]), key[a] >> (t_key - t));
            }
            assert_eq!(tree.levels[t as usize].child(node), NONE);
        }
    }
}
