//! Morton (Z-order) codes of 3-D integer points, and of real points quantised in a box.
//!
//! A code interleaves the low [`BITS`] bits of each coordinate, x lowest: bit `i` of axis `a`
//! lands on bit `3i + a`. Sorting by code walks a Z-shaped space-filling curve, so points
//! consecutive in that order are close in space; the octree, the density estimator, the k-d
//! tree of the normal estimator and the evaluation's queries all sort by it for locality.

/// Bits kept per coordinate (3 × 21 = 63 bits of code).
pub(crate) const BITS: u32 = 21;
/// The largest coordinate that fits [`BITS`] bits.
const MAX: u64 = (1 << BITS) - 1;

/// Spreads the low 21 bits of `x` to every third bit (bit `i` to bit `3i`); higher bits of `x`
/// are ignored.
#[inline]
pub(crate) fn spread(x: u64) -> u64 {
    let mut x = x & MAX;
    x = (x | x << 32) & 0x1f_0000_0000_ffff;
    x = (x | x << 16) & 0x1f_0000_ff00_00ff;
    x = (x | x << 8) & 0x100f_00f0_0f00_f00f;
    x = (x | x << 4) & 0x10c3_0c30_c30c_30c3;
    (x | x << 2) & 0x1249_2492_4924_9249
}

/// The Morton code of `c` (the low 21 bits of each coordinate, x lowest).
#[inline]
pub(crate) fn encode(c: [u64; 3]) -> u64 {
    spread(c[0]) | spread(c[1]) << 1 | spread(c[2]) << 2
}

/// Gathers every third bit of `x` (bit `3i` to bit `i`): the inverse of [`spread`].
#[inline]
pub(crate) fn compact(x: u64) -> u64 {
    let mut x = x & 0x1249_2492_4924_9249;
    x = (x | x >> 2) & 0x10c3_0c30_c30c_30c3;
    x = (x | x >> 4) & 0x100f_00f0_0f00_f00f;
    x = (x | x >> 8) & 0x1f_0000_ff00_00ff;
    x = (x | x >> 16) & 0x1f_0000_0000_ffff;
    (x | x >> 32) & MAX
}

/// The point whose Morton code is `m`: the inverse of [`encode`].
#[inline]
pub(crate) fn decode(m: u64) -> [u64; 3] {
    [compact(m), compact(m >> 1), compact(m >> 2)]
}

/// Morton codes of real points: each coordinate is quantised to 21 bits over the cube whose
/// corner is the low corner of a bounding box and whose side is the box's longest extent.
#[derive(Debug, Clone, Copy)]
pub(crate) struct BoxKeys {
    lo: [f64; 3],
    scale: f64,
}

impl BoxKeys {
    /// Keys over the bounding box of `points` (all keys are 0 when the box is empty, a single
    /// point, or unbounded).
    pub(crate) fn around(points: impl IntoIterator<Item = [f64; 3]>) -> Self {
        let mut lo = [f64::INFINITY; 3];
        let mut hi = [f64::NEG_INFINITY; 3];
        for p in points {
            for a in 0..3 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        let span = (0..3).map(|a| hi[a] - lo[a]).fold(0.0, f64::max);
        let scale = if span > 0.0 && span.is_finite() {
            MAX as f64 / span
        } else {
            0.0
        };
        BoxKeys { lo, scale }
    }

    /// The key of `p`. Saturating float-to-integer casts keep points outside the box, and NaN
    /// coordinates, in range.
    #[inline]
    pub(crate) fn key(&self, p: [f64; 3]) -> u64 {
        encode(std::array::from_fn(|a| {
            (((p[a] - self.lo[a]) * self.scale) as u64).min(MAX)
        }))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use proptest::prelude::*;

    /// Bit by bit, as the definition says.
    fn naive(c: [u64; 3]) -> u64 {
        let mut m = 0u64;
        for bit in 0..BITS {
            for (a, &v) in c.iter().enumerate() {
                m |= ((v >> bit) & 1) << (3 * bit as usize + a);
            }
        }
        m
    }

    #[test]
    fn interleaves_x_lowest() {
        assert_eq!(encode([1, 0, 0]), 1);
        assert_eq!(encode([0, 1, 0]), 2);
        assert_eq!(encode([0, 0, 1]), 4);
        assert_eq!(encode([3, 0, 0]), 0b1001);
        assert_eq!(encode([MAX, 0, 0]) >> 60, 1);
        assert_eq!(encode([MAX; 3]), (1 << 63) - 1);
        // Bits above the 21st are ignored.
        assert_eq!(encode([1 << 21 | 5, u64::MAX, 0]), encode([5, MAX, 0]));
    }

    #[test]
    fn box_keys_cover_the_box() {
        let keys = BoxKeys::around([[0.0, 0.0, 0.0], [2.0, 1.0, 1.0]]);
        assert_eq!(keys.key([0.0; 3]), 0);
        assert_eq!(keys.key([2.0, 0.0, 0.0]), encode([MAX, 0, 0]));
        // The cube's side is the longest extent, so y and z only reach half way.
        assert_eq!(keys.key([0.0, 1.0, 0.0]), encode([0, MAX / 2, 0]));
        // Outside the box and NaN saturate.
        assert_eq!(keys.key([-1.0, 9.0, f64::NAN]), encode([0, MAX, 0]));
        assert_eq!(BoxKeys::around([[1.0; 3]]).key([5.0; 3]), 0);
        assert_eq!(BoxKeys::around([]).key([5.0; 3]), 0);
    }

    proptest! {
        #[test]
        fn encode_matches_the_bit_loop(x: u64, y: u64, z: u64) {
            prop_assert_eq!(encode([x, y, z]), naive([x, y, z]));
        }

        #[test]
        fn spread_matches_the_bit_loop(x: u64) {
            prop_assert_eq!(spread(x), naive([x, 0, 0]));
        }

        #[test]
        fn decode_inverts_encode(x in 0..=MAX, y in 0..=MAX, z in 0..=MAX) {
            prop_assert_eq!(decode(encode([x, y, z])), [x, y, z]);
        }
    }
}
