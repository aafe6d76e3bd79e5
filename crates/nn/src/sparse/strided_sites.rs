//! The output sites of a strided sparse convolution (every site some input feeds), in
//! batch-major order, and the row of each by its linear index.
//!
//! Why a bitmap: the outputs are the distinct targets of every (input, offset) pair, about
//! eight per input for a 3×3×3 kernel of stride 2. Sorting those targets (with their inputs
//! and offsets) was the larger part of a strided rulebook, the host's work of every frame
//! on a GPU machine. One bit per output cell, set from all inputs in parallel, lists the
//! outputs in index order by a scan of the words, and a running count of the set bits before
//! each word gives any output's row in constant time. A grid too large for the bitmap (more
//! than [`BITMAP_LIMIT_BITS`] cells over the batch) takes the sort of the distinct indices.

use super::rulebook::ConvGeometry;
use super::sites::{SparseSites, decode_key, linear_key};
use rayon::prelude::*;
use std::sync::atomic::{AtomicU64, Ordering};

/// Output cells (over the whole batch) up to which the outputs are found by a bitmap: 2³⁰
/// bits, 128 MiB; the published Voxel R-CNN grid's first strided stage holds 11.8 million
/// cells an item.
pub(crate) const BITMAP_LIMIT_BITS: u64 = 1 << 30;

/// The outputs of one strided layer over given input sites.
pub(crate) struct StridedOutputs {
    /// (batch, z, y, x) of every output, batch-major: its row.
    pub coords: Vec<[i32; 4]>,
    pub rows: OutputRows,
}

/// An output's row from its linear index.
pub(crate) enum OutputRows {
    /// One bit per output cell, and the set bits before each word.
    Bitmap { words: Vec<u64>, before: Vec<u32> },
    /// The outputs' indices, ascending.
    Sorted(Vec<u64>),
}

impl StridedOutputs {
    pub fn new(sites: &SparseSites, geometry: &ConvGeometry) -> StridedOutputs {
        Self::with_bitmap_limit(sites, geometry, BITMAP_LIMIT_BITS)
    }

    /// [`StridedOutputs::new`] with the bitmap used up to `limit_bits` cells (tests force
    /// the sort with a small limit).
    pub fn with_bitmap_limit(
        sites: &SparseSites,
        geometry: &ConvGeometry,
        limit_bits: u64,
    ) -> StridedOutputs {
        let out_shape = geometry.output_shape(sites.spatial_shape());
        let cells = sites.batch_size() as u64 * out_shape.iter().product::<usize>() as u64;
        let targets = |c: &[i32; 4], f: &mut dyn FnMut(u64)| {
            geometry.for_each_target(c, out_shape, |_, o| f(linear_key(o, out_shape)));
        };
        if cells <= limit_bits {
            let words: Vec<AtomicU64> =
                (0..cells.div_ceil(64)).map(|_| AtomicU64::new(0)).collect();
            sites.coords().par_iter().for_each(|c| {
                targets(c, &mut |key| {
                    words[(key / 64) as usize].fetch_or(1 << (key % 64), Ordering::Relaxed);
                })
            });
            let words: Vec<u64> = words.into_iter().map(AtomicU64::into_inner).collect();
            let mut before = Vec::with_capacity(words.len());
            let mut coords = Vec::new();
            for (w, &word) in words.iter().enumerate() {
                before.push(coords.len() as u32);
                let mut bits = word;
                while bits != 0 {
                    let key = w as u64 * 64 + bits.trailing_zeros() as u64;
                    coords.push(decode_key(key, out_shape));
                    bits &= bits - 1;
                }
            }
            StridedOutputs {
                coords,
                rows: OutputRows::Bitmap { words, before },
            }
        } else {
            let mut keys: Vec<u64> = sites
                .coords()
                .par_iter()
                .fold(Vec::new, |mut keys, c| {
                    targets(c, &mut |key| keys.push(key));
                    keys
                })
                .reduce(Vec::new, |mut a, mut b| {
                    a.append(&mut b);
                    a
                });
            keys.par_sort_unstable();
            keys.dedup();
            StridedOutputs {
                coords: keys.iter().map(|&k| decode_key(k, out_shape)).collect(),
                rows: OutputRows::Sorted(keys),
            }
        }
    }
}

impl OutputRows {
    /// The row of the output at linear index `key`, which must be an output.
    pub fn row(&self, key: u64) -> u32 {
        match self {
            OutputRows::Bitmap { words, before } => {
                let (w, bit) = ((key / 64) as usize, key % 64);
                debug_assert!(words[w] >> bit & 1 == 1, "{key} is an output");
                before[w] + (words[w] & ((1u64 << bit) - 1)).count_ones()
            }
            OutputRows::Sorted(keys) => {
                keys.binary_search(&key)
                    .unwrap_or_else(|_| panic!("{key} is an output")) as u32
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bitmap and the sort list the same outputs, and give every output its row.
    #[test]
    fn bitmap_and_sort_agree() {
        let coords: Vec<[i32; 4]> = (0..200)
            .map(|i| [i % 2, (i * 7) % 5, (i * 13) % 9, (i * 29) % 70])
            .collect();
        let mut coords_unique = coords.clone();
        coords_unique.sort();
        coords_unique.dedup();
        let sites = SparseSites::new(coords_unique, [5, 9, 70], 2).unwrap();
        for geometry in [
            ConvGeometry::strided([3; 3], [2; 3], [1; 3]),
            ConvGeometry::strided([3, 1, 1], [2, 1, 1], [0; 3]),
        ] {
            let bitmap = StridedOutputs::new(&sites, &geometry);
            assert!(matches!(bitmap.rows, OutputRows::Bitmap { .. }));
            let sorted = StridedOutputs::with_bitmap_limit(&sites, &geometry, 0);
            assert!(matches!(sorted.rows, OutputRows::Sorted(_)));
            assert_eq!(bitmap.coords, sorted.coords);
            let out_shape = geometry.output_shape(sites.spatial_shape());
            for (row, &c) in bitmap.coords.iter().enumerate() {
                let key = linear_key(c, out_shape);
                assert_eq!(bitmap.rows.row(key), row as u32);
                assert_eq!(sorted.rows.row(key), row as u32);
            }
        }
    }
}
