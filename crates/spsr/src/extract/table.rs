//! A fixed-capacity open-addressing hash table from packed `u64` keys to `u32` values that
//! many threads can fill at once (lock-free insertion by compare-and-swap), then read.
//!
//! Which slot a key lands in depends on the insertion order, so callers never expose slot
//! numbers: they store deterministic values (ranks, indices) and read those back.

use std::sync::atomic::{AtomicU32, AtomicU64, Ordering::Relaxed};

/// Marks an empty slot. Packed keys never have all bits set.
pub(super) const EMPTY: u64 = u64::MAX;

/// Concurrent insert-only hash table (linear probing).
pub(super) struct Table {
    keys: Vec<AtomicU64>,
    vals: Vec<AtomicU32>,
    mask: usize,
}

/// A strong 64-bit mixer (the MurmurHash3 finaliser), so structured keys spread evenly.
#[inline]
fn mix(mut k: u64) -> u64 {
    k ^= k >> 33;
    k = k.wrapping_mul(0xff51_afd7_ed55_8ccd);
    k ^= k >> 33;
    k = k.wrapping_mul(0xc4ce_b9fe_1a85_ec53);
    k ^ (k >> 33)
}

impl Table {
    /// A table able to hold `n` keys with a load factor of at most about 0.7.
    pub(super) fn with_capacity(n: usize) -> Table {
        let cap = ((n.max(8) as f64 * 1.45) as usize).next_power_of_two();
        Table {
            keys: (0..cap).map(|_| AtomicU64::new(EMPTY)).collect(),
            vals: (0..cap).map(|_| AtomicU32::new(u32::MAX)).collect(),
            mask: cap - 1,
        }
    }

    /// Inserts `key` if absent; returns its slot, or `None` when the table is full.
    #[inline]
    pub(super) fn insert(&self, key: u64) -> Option<u32> {
        let mut i = mix(key) as usize & self.mask;
        for _ in 0..=self.mask {
            let cur = self.keys[i].load(Relaxed);
            if cur == key {
                return Some(i as u32);
            }
            if cur == EMPTY {
                match self.keys[i].compare_exchange(EMPTY, key, Relaxed, Relaxed) {
                    Ok(_) => return Some(i as u32),
                    Err(actual) if actual == key => return Some(i as u32),
                    Err(_) => {}
                }
            }
            i = (i + 1) & self.mask;
        }
        None
    }

    /// The slot of `key`, if present.
    #[inline]
    pub(super) fn slot(&self, key: u64) -> Option<u32> {
        let mut i = mix(key) as usize & self.mask;
        for _ in 0..=self.mask {
            let cur = self.keys[i].load(Relaxed);
            if cur == key {
                return Some(i as u32);
            }
            if cur == EMPTY {
                return None;
            }
            i = (i + 1) & self.mask;
        }
        None
    }

    /// Whether `key` is present.
    #[inline]
    pub(super) fn contains(&self, key: u64) -> bool {
        self.slot(key).is_some()
    }

    /// The value stored for `key`, if present.
    #[inline]
    pub(super) fn get(&self, key: u64) -> Option<u32> {
        self.slot(key).map(|s| self.vals[s as usize].load(Relaxed))
    }

    /// Stores `val` in slot `slot`.
    #[inline]
    pub(super) fn set(&self, slot: u32, val: u32) {
        self.vals[slot as usize].store(val, Relaxed);
    }

    /// The value in slot `slot`.
    #[inline]
    pub(super) fn val(&self, slot: u32) -> u32 {
        self.vals[slot as usize].load(Relaxed)
    }

    /// All keys present, in slot order (which depends on insertion order).
    pub(super) fn keys(&self) -> Vec<u64> {
        use rayon::prelude::*;
        self.keys
            .par_iter()
            .map(|k| k.load(Relaxed))
            .filter(|&k| k != EMPTY)
            .collect()
    }
}
