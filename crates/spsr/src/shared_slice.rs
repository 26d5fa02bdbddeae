//! A slice that several threads write at disjoint indices (multi-colour Gauss–Seidel,
//! coloured accumulation): the one place where the numeric core shares a buffer unsafely.

/// A slice shared between threads that write disjoint elements (multi-colour Gauss–Seidel,
/// coloured accumulation).
pub struct SharedSlice<T> {
    ptr: *mut T,
    len: usize,
}

// SAFETY: access goes through `get`/`set`, whose callers guarantee disjoint writes.
unsafe impl<T: Send> Sync for SharedSlice<T> {}

impl<T: Copy> SharedSlice<T> {
    pub fn new(s: &mut [T]) -> Self {
        Self {
            ptr: s.as_mut_ptr(),
            len: s.len(),
        }
    }

    /// # Safety
    /// No concurrent write to element `i`.
    #[inline]
    pub unsafe fn get(&self, i: usize) -> T {
        debug_assert!(i < self.len);
        *self.ptr.add(i)
    }

    /// Elements `i..i + N`.
    ///
    /// # Safety
    /// No concurrent write to any of them.
    #[inline]
    pub unsafe fn get_array<const N: usize>(&self, i: usize) -> [T; N] {
        debug_assert!(i + N <= self.len);
        self.ptr.add(i).cast::<[T; N]>().read()
    }

    /// # Safety
    /// No concurrent access to element `i`.
    #[inline]
    pub unsafe fn set(&self, i: usize, v: T) {
        debug_assert!(i < self.len);
        *self.ptr.add(i) = v;
    }
}

/// `v` cut into consecutive slices of the given lengths (which must sum to at most its
/// length): the parts that threads fill each on their own.
pub fn split_into<T>(mut v: &mut [T], lens: impl Iterator<Item = usize>) -> Vec<&mut [T]> {
    lens.map(|n| {
        let (head, tail) = std::mem::take(&mut v).split_at_mut(n);
        v = tail;
        head
    })
    .collect()
}
