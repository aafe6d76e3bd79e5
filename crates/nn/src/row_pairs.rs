//! Lists turned around: for every row of one side, the (list, position) entries that name
//! it, in list order (compressed rows), and the row-wise sums they drive.
//!
//! Why: a gather's backward and a scatter-add both add many source rows into each target
//! row. Done per source list, the additions into a row happen in list order but one list at a
//! time, which cannot be split over threads without changing a sum's order. Turned around,
//! each target row holds its entries in that same order, so rows split over threads add
//! exactly what the serial loop added, in the same order, to the bit. The sparse
//! convolution's rulebooks (one list per kernel offset) and LFA's and the RoI pool's
//! neighbourhoods (one list) share it.

use crate::buffers::par_chunks_filled;
use rayon::prelude::*;

/// Rows handed to one task by the row-parallel loops.
pub(crate) const ROWS_PER_TASK: usize = 256;

/// For every row, the (list, position) entries that name it, in list order.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct RowPairs {
    /// [rows + 1]: row r's entries are `entries[starts[r]..starts[r + 1]]`.
    starts: Vec<usize>,
    /// (index of the list, position within it).
    entries: Vec<(u32, u32)>,
}

impl RowPairs {
    /// From lists of rows (each below `rows`), in order.
    pub fn new<'a>(rows: usize, lists: impl Iterator<Item = &'a [u32]> + Clone) -> RowPairs {
        let mut starts = vec![0usize; rows + 1];
        for list in lists.clone() {
            for &r in list {
                starts[r as usize + 1] += 1;
            }
        }
        for r in 0..rows {
            starts[r + 1] += starts[r];
        }
        let mut next = starts[..rows].to_vec();
        let mut entries = vec![(0u32, 0u32); starts[rows]];
        for (j, list) in lists.enumerate() {
            for (p, &r) in list.iter().enumerate() {
                let at = &mut next[r as usize];
                entries[*at] = (j as u32, p as u32);
                *at += 1;
            }
        }
        RowPairs { starts, entries }
    }

    /// Row `row`'s (list, position) entries, in list order.
    pub fn of(&self, row: usize) -> &[(u32, u32)] {
        &self.entries[self.starts[row]..self.starts[row + 1]]
    }

    /// [rows + 1]: row r's entries are `entries()[starts()[r]..starts()[r + 1]]`.
    pub fn starts(&self) -> &[usize] {
        &self.starts
    }

    /// Every row's entries, row after row.
    pub fn entries(&self) -> &[(u32, u32)] {
        &self.entries
    }

    /// Adds into each [c]-row r of `target` first `first[r]` (where given), then row p of
    /// `sources[j]` for every (j, p) entry of r, in that order; rows in parallel.
    pub(crate) fn add_into<S: AsRef<[f32]> + Sync>(
        &self,
        target: &mut [f32],
        c: usize,
        first: Option<&[f32]>,
        sources: &[S],
    ) {
        if c == 0 {
            return;
        }
        target
            .par_chunks_mut(c * ROWS_PER_TASK)
            .enumerate()
            .for_each(|(task, chunk)| self.add_chunk(task, chunk, c, first, sources));
    }

    /// [`RowPairs::add_into`] a zero [rows, c] target, zeroed chunk by chunk by the tasks
    /// that fill it (no serial pass first).
    pub(crate) fn sums<S: AsRef<[f32]> + Sync>(
        &self,
        c: usize,
        first: Option<&[f32]>,
        sources: &[S],
    ) -> Vec<f32> {
        let rows = self.starts.len() - 1;
        par_chunks_filled(rows * c, c * ROWS_PER_TASK, |task, chunk| {
            self.add_chunk(task, chunk, c, first, sources)
        })
    }

    /// The additions of [`RowPairs::add_into`] for the rows of task `task`'s chunk.
    fn add_chunk<S: AsRef<[f32]>>(
        &self,
        task: usize,
        chunk: &mut [f32],
        c: usize,
        first: Option<&[f32]>,
        sources: &[S],
    ) {
        for (i, dst) in chunk.chunks_exact_mut(c).enumerate() {
            let row = task * ROWS_PER_TASK + i;
            let rows = first.map(|f| &f[row * c..][..c]).into_iter().chain(
                self.of(row)
                    .iter()
                    .map(|&(j, p)| &sources[j as usize].as_ref()[p as usize * c..][..c]),
            );
            for src in rows {
                for (d, &s) in dst.iter_mut().zip(src) {
                    *d += s;
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Each row's entries are the positions that name it, in list order; rows no list
    /// names have none.
    #[test]
    fn row_pairs_list_each_rows_pairs_in_rule_order() {
        let lists: [&[u32]; 3] = [&[2, 0], &[0, 3], &[3]];
        let by_row = RowPairs::new(5, lists.iter().copied());
        assert_eq!(by_row.of(0), &[(0, 1), (1, 0)]);
        assert_eq!(by_row.of(1), &[] as &[(u32, u32)]);
        assert_eq!(by_row.of(2), &[(0, 0)]);
        assert_eq!(by_row.of(3), &[(1, 1), (2, 0)]);
        assert_eq!(by_row.of(4), &[] as &[(u32, u32)]);
    }
}
