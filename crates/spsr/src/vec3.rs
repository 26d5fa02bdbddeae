//! Small vector algebra on `[f64; 3]`, shared by the mesh, metrics, trimming, normals and
//! extraction code.
//!
//! Every function spells its arithmetic out component by component in a fixed order (e.g.
//! `dot` is `a0·b0 + a1·b1 + a2·b2`, summed left to right) so that results are bit-for-bit
//! the same as the hand-written expressions they replaced: reconstructed meshes are pinned
//! by hash, and floating-point addition is not associative.

/// A point or vector in 3-space.
pub(crate) type V3 = [f64; 3];

/// `a + b`.
#[inline]
pub(crate) fn add(a: V3, b: V3) -> V3 {
    [a[0] + b[0], a[1] + b[1], a[2] + b[2]]
}

/// `a − b`.
#[inline]
pub(crate) fn sub(a: V3, b: V3) -> V3 {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// `a · s`.
#[inline]
pub(crate) fn scale(a: V3, s: f64) -> V3 {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// `a · b`, summed in axis order.
#[inline]
pub(crate) fn dot(a: V3, b: V3) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// `a × b`.
#[inline]
pub(crate) fn cross(a: V3, b: V3) -> V3 {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// `|a|²`.
#[inline]
pub(crate) fn norm2(a: V3) -> f64 {
    dot(a, a)
}

/// `|a|`.
#[inline]
pub(crate) fn norm(a: V3) -> f64 {
    norm2(a).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn basic_identities() {
        let (a, b) = ([1.0, 2.0, 3.0], [-4.0, 0.5, 2.0]);
        assert_eq!(add(a, b), [-3.0, 2.5, 5.0]);
        assert_eq!(sub(a, b), [5.0, 1.5, 1.0]);
        assert_eq!(scale(a, 2.0), [2.0, 4.0, 6.0]);
        assert_eq!(dot(a, b), 3.0);
        assert_eq!(cross([1.0, 0.0, 0.0], [0.0, 1.0, 0.0]), [0.0, 0.0, 1.0]);
        assert_eq!(dot(cross(a, b), a), 0.0);
        assert_eq!(norm2(a), 14.0);
        assert_eq!(norm([3.0, 4.0, 0.0]), 5.0);
    }

    #[test]
    fn dot_sums_in_axis_order() {
        // (1e17 + 1) − 1e17 loses the 1; (1e17 − 1e17) + 1 keeps it.
        let ones = [1.0; 3];
        assert_eq!(dot([1e17, 1.0, -1e17], ones), 0.0);
        assert_eq!(dot([1e17, -1e17, 1.0], ones), 1.0);
    }
}
