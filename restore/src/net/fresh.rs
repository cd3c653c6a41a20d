//! Kernel outputs handed out without zeroing them first.
//!
//! Every direct kernel writes each value of its output once, so the zeros of `vec![0.0; n]`
//! were never read; writing them (the allocator's `memset`) was about 5 % of a `tiny`
//! forward pass.

use rayon::prelude::*;
use std::mem::MaybeUninit;

/// `len` values made in parallel, `chunk` at a time (the last may be shorter): `fill(i,
/// dst)` gets chunk `i` and **must write every value of it** before returning; it is
/// handed memory that holds nothing yet and must not read it.
pub fn filled(len: usize, chunk: usize, fill: impl Fn(usize, &mut [f32]) + Sync) -> Vec<f32> {
    let mut out = Vec::<f32>::with_capacity(len);
    if len > 0 {
        out.spare_capacity_mut()[..len]
            .par_chunks_mut(chunk.max(1))
            .enumerate()
            .for_each(|(i, dst)| {
                // SAFETY: `MaybeUninit<f32>` has `f32`'s layout, and the contract above has
                // `fill` write before it reads.
                let dst = unsafe { &mut *(dst as *mut [MaybeUninit<f32>] as *mut [f32]) };
                fill(i, dst);
            });
    }
    // SAFETY: the tasks above wrote every one of the `len` values.
    unsafe { out.set_len(len) };
    out
}

/// `len` values made by one call: `fill` gets them all and **must write every one** before
/// returning (in whatever order or split it likes); like [`filled`], it is handed memory that
/// holds nothing yet and must not read it.
pub fn written(len: usize, fill: impl FnOnce(&mut [f32])) -> Vec<f32> {
    let mut out = Vec::<f32>::with_capacity(len);
    let dst = &mut out.spare_capacity_mut()[..len];
    // SAFETY: as in `filled`.
    fill(unsafe { &mut *(dst as *mut [MaybeUninit<f32>] as *mut [f32]) });
    // SAFETY: `fill` wrote every one of the `len` values.
    unsafe { out.set_len(len) };
    out
}

#[cfg(test)]
mod tests {
    use super::{filled, written};

    #[test]
    fn every_chunk_lands_in_its_place() {
        for (len, chunk) in [(0, 4), (1, 4), (10, 3), (12, 4), (1000, 64)] {
            let v = filled(len, chunk, |i, dst| {
                for (j, d) in dst.iter_mut().enumerate() {
                    *d = (i * chunk + j) as f32;
                }
            });
            assert_eq!(v.len(), len);
            assert!(
                v.iter().enumerate().all(|(k, &x)| x == k as f32),
                "{len}/{chunk}"
            );
        }
    }

    #[test]
    fn written_hands_over_every_value_in_place() {
        for len in [0, 1, 7, 1000] {
            let v = written(len, |dst| {
                // Two halves from the two ends, as the gate's gradient writes its planes.
                let (a, b) = dst.split_at_mut(len / 2);
                a.iter_mut().enumerate().for_each(|(i, d)| *d = i as f32);
                b.iter_mut()
                    .enumerate()
                    .for_each(|(i, d)| *d = (len / 2 + i) as f32);
            });
            assert_eq!(v.len(), len);
            assert!(v.iter().enumerate().all(|(k, &x)| x == k as f32), "{len}");
        }
    }
}
