//! Output buffers of the custom operations, written in parallel without a serial zeroing
//! pass first.
//!
//! Why: `vec![0f32; n]` zeroes the whole buffer on the calling thread before the parallel
//! loop that writes it (the allocator hands back reused memory, which must be cleared). In
//! the voxel training steps that memset ran on one core while the other waited: a few
//! percent of the step, on the critical path. Here each parallel task zeroes only its own
//! chunk, just before it writes it (while the chunk is in its core's cache), and an output
//! whose every value is written ([`par_chunks_written`]: batch norm's) is not zeroed at all.

use rayon::prelude::*;
use std::mem::MaybeUninit;

/// A vector of `len` values, `fill(i, chunk)` writing chunk i (values `i·chunk_len..`, the
/// last chunk shorter) on the rayon pool; each chunk is zero when `fill` gets it, so
/// `fill` may accumulate or leave values at zero.
pub fn par_chunks_filled(
    len: usize,
    chunk_len: usize,
    fill: impl Fn(usize, &mut [f32]) + Sync,
) -> Vec<f32> {
    par_chunks_written(len, chunk_len, |i, chunk| {
        chunk.fill(MaybeUninit::new(0.0));
        // SAFETY: every element of `chunk` was initialised on the line above, and
        // `MaybeUninit<f32>` has the layout of `f32`.
        let chunk = unsafe { &mut *(chunk as *mut [MaybeUninit<f32>] as *mut [f32]) };
        fill(i, chunk);
    })
}

/// A vector of `len` values, `write(i, chunk)` writing chunk i (values `i·chunk_len..`, the
/// last chunk shorter) on the rayon pool, for outputs whose every value is computed: the
/// chunk is not zeroed first, so `write` must write each of its elements (the vector is
/// made of what it wrote).
pub fn par_chunks_written(
    len: usize,
    chunk_len: usize,
    write: impl Fn(usize, &mut [MaybeUninit<f32>]) + Sync,
) -> Vec<f32> {
    let mut out: Vec<f32> = Vec::with_capacity(len);
    out.spare_capacity_mut()[..len]
        .par_chunks_mut(chunk_len.max(1))
        .enumerate()
        .for_each(|(i, chunk)| write(i, chunk));
    // SAFETY: the chunks cover indices 0..len and `write` initialises every element of its
    // chunk (its contract; the callers' tests compare every value with burn's).
    unsafe { out.set_len(len) };
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn every_chunk_is_zeroed_then_filled_in_order() {
        // Reused memory first: a freed buffer of nonzero values of the same size.
        drop(vec![7f32; 1003]);
        let v = par_chunks_filled(1003, 10, |i, chunk| {
            assert!(chunk.iter().all(|&x| x == 0.0));
            assert_eq!(chunk.len(), if i == 100 { 3 } else { 10 });
            for (j, x) in chunk.iter_mut().enumerate() {
                if j % 2 == 0 {
                    *x += (i * 10 + j) as f32;
                }
            }
        });
        let expected: Vec<f32> = (0..1003)
            .map(|k| if k % 10 % 2 == 0 { k as f32 } else { 0.0 })
            .collect();
        assert_eq!(v, expected);
    }

    #[test]
    fn empty_and_zero_width_buffers() {
        assert!(par_chunks_filled(0, 0, |_, _| panic!("no chunk")).is_empty());
        assert!(par_chunks_filled(0, 4, |_, _| panic!("no chunk")).is_empty());
        assert!(par_chunks_written(0, 4, |_, _| panic!("no chunk")).is_empty());
    }

    #[test]
    fn written_chunks_come_back_in_order() {
        drop(vec![7f32; 1003]);
        let v = par_chunks_written(1003, 10, |i, chunk| {
            assert_eq!(chunk.len(), if i == 100 { 3 } else { 10 });
            for (j, x) in chunk.iter_mut().enumerate() {
                x.write((i * 10 + j) as f32);
            }
        });
        assert_eq!(v, (0..1003).map(|k| k as f32).collect::<Vec<_>>());
    }
}
