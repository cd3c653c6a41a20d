//! One buffer written by parallel tasks that each own a known part of it.
//!
//! The forward's tiles write their pixels straight into the image, and binning scatters each
//! key to the slot its counts reserved for it. The parts are disjoint by construction (tile
//! rectangles do not overlap; a prefix sum gives every writer its own range), but the parts
//! are computed indices the borrow checker cannot split a slice along. Every access is
//! bounds-checked; what the caller promises is only that no two tasks touch the same index.

use std::marker::PhantomData;

pub(crate) struct Disjoint<'a, T> {
    ptr: *mut T,
    len: usize,
    _buf: PhantomData<&'a mut [T]>,
}

// SAFETY: a `Disjoint` only hands out parts of the buffer it exclusively borrowed, under the
// contract of its unsafe methods that parts used at the same time do not overlap: the same
// guarantee `split_at_mut` gives, so it may cross threads whenever `&mut [T]` may.
unsafe impl<T: Send> Send for Disjoint<'_, T> {}
// SAFETY: as above.
unsafe impl<T: Send> Sync for Disjoint<'_, T> {}

impl<'a, T: Copy> Disjoint<'a, T> {
    pub fn new(buf: &'a mut [T]) -> Self {
        Self {
            ptr: buf.as_mut_ptr(),
            len: buf.len(),
            _buf: PhantomData,
        }
    }

    /// The part `start .. start + len`.
    ///
    /// # Safety
    /// No other part in use at the same time overlaps it.
    #[inline]
    #[allow(clippy::mut_from_ref)]
    pub unsafe fn part(&self, start: usize, len: usize) -> &mut [T] {
        assert!(
            start <= self.len && len <= self.len - start,
            "part out of bounds"
        );
        // SAFETY: in bounds (checked); exclusive by the caller's promise.
        unsafe { std::slice::from_raw_parts_mut(self.ptr.add(start), len) }
    }

    /// Writes `value` at `index`.
    ///
    /// # Safety
    /// No other task reads or writes `index` at the same time.
    #[inline]
    pub unsafe fn write(&self, index: usize, value: T) {
        assert!(index < self.len, "index out of bounds");
        // SAFETY: in bounds (checked); exclusive by the caller's promise; `T: Copy` has no
        // destructor to skip.
        unsafe { self.ptr.add(index).write(value) }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use rayon::prelude::*;

    #[test]
    fn parallel_writers_of_disjoint_parts_fill_the_buffer() {
        let mut buf = vec![0u32; 10_000];
        let d = Disjoint::new(&mut buf);
        (0..100usize).into_par_iter().for_each(|p| {
            // SAFETY: part p is 100 p .. 100 p + 100, its own.
            let part = unsafe { d.part(p * 100, 100) };
            for (i, v) in part.iter_mut().enumerate() {
                *v = (p * 100 + i) as u32;
            }
        });
        assert!(buf.iter().enumerate().all(|(i, &v)| v == i as u32));
    }

    #[test]
    #[should_panic(expected = "out of bounds")]
    fn a_part_past_the_end_is_refused() {
        let mut buf = vec![0u8; 4];
        let d = Disjoint::new(&mut buf);
        // SAFETY: the only part; the call panics before any access.
        let _ = unsafe { d.part(2, 3) };
    }
}
