//! A fixed-capacity open-addressing hash table from packed `u64` keys to `u32` values that
//! many threads can fill at once (lock-free insertion by compare-and-swap), then read.
//!
//! Which slot a key lands in depends on the insertion order, so callers never expose slot
//! numbers: they store deterministic values (ranks, indices, minima) and read those back.
//!
//! Keys are packed integer points (20 bits per axis, see `super::pack`). The hash keeps
//! 2×2×2 blocks of neighbouring points in 8 consecutive slots, so the corners of nearby
//! cells share cache lines; the blocks themselves are spread by a strong mixer over any
//! number of groups of 8 slots (not a power of two: rounding up to one left the table of a
//! million-point mesh at depth 10 a third full, 134 MB made by one thread; issue 20).

use std::sync::atomic::{AtomicU32, AtomicU64, AtomicUsize, Ordering::Relaxed};

use rayon::prelude::*;

/// Marks an empty slot. Packed keys never have all bits set.
pub(super) const EMPTY: u64 = u64::MAX;

#[repr(C, align(16))]
struct Slot {
    key: AtomicU64,
    val: AtomicU32,
}

/// Concurrent insert-only hash table (linear probing).
pub(super) struct Table {
    slots: Vec<Slot>,
    /// Groups of 8 slots.
    groups: usize,
    /// Keys inserted so far, and the most the table accepts (a load factor of 0.8) before
    /// `insert` reports it full.
    len: AtomicUsize,
    limit: usize,
}

/// A strong 64-bit mixer (the MurmurHash3 finaliser).
#[inline]
fn mix(mut k: u64) -> u64 {
    k ^= k >> 33;
    k = k.wrapping_mul(0xff51_afd7_ed55_8ccd);
    k ^= k >> 33;
    k = k.wrapping_mul(0xc4ce_b9fe_1a85_ec53);
    k ^ (k >> 33)
}

/// Bits of each axis (and of the edge axis tag above them) that select the 2×2×2 block.
const LOW: u64 = 1 | 1 << 20 | 1 << 40;

/// The first slot to probe for `k` in a table of `groups` groups of 8 slots: the group from
/// the mixed key with the 2×2×2 block's bits cleared (scaled to the groups by a
/// multiplication, which needs no power of two), the slot in the group from those bits.
#[inline]
fn start(k: u64, groups: usize) -> usize {
    let off = (k & 1) | (k >> 19 & 2) | (k >> 38 & 4);
    let group = (u128::from(mix(k & !LOW)) * groups as u128) >> 64;
    (group as usize) << 3 | off as usize
}

impl Table {
    /// A table able to hold `n` keys with a load factor of at most about 0.7, its slots made
    /// in parallel.
    pub(super) fn with_capacity(n: usize) -> Table {
        let groups = (n.max(8) as f64 * 1.45 / 8.0).ceil() as usize;
        let cap = groups * 8;
        let slots = (0..cap)
            .into_par_iter()
            .map(|_| Slot {
                key: AtomicU64::new(EMPTY),
                val: AtomicU32::new(u32::MAX),
            })
            .collect();
        Table {
            slots,
            groups,
            len: AtomicUsize::new(0),
            limit: cap / 5 * 4,
        }
    }

    /// The slot after `i`, wrapping round.
    #[inline]
    fn next(&self, i: usize) -> usize {
        if i + 1 == self.slots.len() {
            0
        } else {
            i + 1
        }
    }

    /// Inserts `key` if absent; returns its slot, or `None` when the table is full.
    #[inline]
    pub(super) fn insert(&self, key: u64) -> Option<u32> {
        let mut i = start(key, self.groups);
        for _ in 0..self.slots.len() {
            let s = &self.slots[i].key;
            let cur = s.load(Relaxed);
            if cur == key {
                return Some(i as u32);
            }
            if cur == EMPTY {
                if self.len.load(Relaxed) >= self.limit {
                    return None;
                }
                match s.compare_exchange(EMPTY, key, Relaxed, Relaxed) {
                    Ok(_) => {
                        self.len.fetch_add(1, Relaxed);
                        return Some(i as u32);
                    }
                    Err(actual) if actual == key => return Some(i as u32),
                    Err(_) => {}
                }
            }
            i = self.next(i);
        }
        None
    }

    /// The slot of `key`, if present.
    #[inline]
    pub(super) fn slot(&self, key: u64) -> Option<u32> {
        let mut i = start(key, self.groups);
        for _ in 0..self.slots.len() {
            let cur = self.slots[i].key.load(Relaxed);
            if cur == key {
                return Some(i as u32);
            }
            if cur == EMPTY {
                return None;
            }
            i = self.next(i);
        }
        None
    }

    /// The value stored for `key`, if present.
    #[inline]
    pub(super) fn get(&self, key: u64) -> Option<u32> {
        self.slot(key).map(|s| self.val(s))
    }

    /// Stores `val` in slot `slot`.
    #[inline]
    pub(super) fn set(&self, slot: u32, val: u32) {
        self.slots[slot as usize].val.store(val, Relaxed);
    }

    /// The value in slot `slot`.
    #[inline]
    pub(super) fn val(&self, slot: u32) -> u32 {
        self.slots[slot as usize].val.load(Relaxed)
    }
}
