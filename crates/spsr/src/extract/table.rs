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

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering::Relaxed};

use rayon::prelude::*;

/// Marks an empty slot. Packed keys never have all bits set.
pub(super) const EMPTY: u64 = u64::MAX;

#[repr(C, align(16))]
struct Slot {
    key: AtomicU64,
    val: AtomicU32,
}

/// Concurrent insert-only hash table (linear probing), made for a known number of keys
/// ([`Table::with_capacity`]). It keeps no count of its keys: a shared count was one atomic
/// add per key on a cache line that every thread wrote, and filling the table of a
/// 2.4-million-vertex mesh took 0.25 s on two threads against 0.18 s on one (issue 20).
pub(super) struct Table {
    slots: Vec<Slot>,
    /// Groups of 8 slots.
    groups: usize,
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
        Table { slots, groups }
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

    /// Inserts `key` if absent; returns its slot, or `None` when every slot holds another key
    /// (more keys than the table was made for).
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
                match s.compare_exchange(EMPTY, key, Relaxed, Relaxed) {
                    Ok(_) => return Some(i as u32),
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

#[cfg(test)]
mod tests {
    use super::*;

    /// Packed keys of `n` distinct points (20 bits per axis).
    fn point_keys(n: u64) -> Vec<u64> {
        (0..n)
            .map(|i| (i % 97) | (i / 97 % 89) << 20 | (i / (97 * 89)) << 40)
            .collect()
    }

    #[test]
    fn keys_inserted_from_many_threads_each_get_one_slot_and_their_value() {
        let keys = point_keys(50_000);
        let table = Table::with_capacity(keys.len());
        // Every key twice, from all threads at once.
        keys.par_iter().chain(keys.par_iter()).for_each(|&k| {
            let slot = table.insert(k).expect("room for every key");
            table.set(slot, (k % 1_000_003) as u32);
        });
        let mut slots: Vec<u32> = keys.iter().map(|&k| table.slot(k).unwrap()).collect();
        for &k in &keys {
            assert_eq!(table.insert(k), table.slot(k));
            assert_eq!(table.get(k), Some((k % 1_000_003) as u32));
        }
        slots.sort_unstable();
        slots.dedup();
        assert_eq!(slots.len(), keys.len());
        assert_eq!(table.get(point_keys(50_001)[50_000]), None);
    }

    #[test]
    fn a_full_table_refuses_a_new_key_and_keeps_its_own() {
        let table = Table::with_capacity(8);
        let cap = table.slots.len() as u64;
        let keys = point_keys(cap + 1);
        for &k in &keys[..cap as usize] {
            assert!(table.insert(k).is_some());
        }
        assert_eq!(table.insert(keys[cap as usize]), None);
        for &k in &keys[..cap as usize] {
            assert!(table.slot(k).is_some());
        }
    }
}
