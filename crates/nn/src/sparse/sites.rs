//! The active sites of a sparse 3D grid and their lookup by linear index.

use rayon::prelude::*;

/// The active sites of a batch of sparse 3D grids: one row per site, as
/// (batch item, z, y, x), every site inside `spatial_shape` = [z, y, x] and listed once.
/// The row order is the order of the feature rows of every tensor on these sites.
#[derive(Debug, Clone)]
pub struct SparseSites {
    coords: Vec<[i32; 4]>,
    spatial_shape: [usize; 3],
    batch_size: usize,
    /// (batch-major linear index, row) of every site, by index. Why a sorted list and not a
    /// hash map: a kernel offset shifts every site's index by one constant, so a rulebook
    /// finds all of an offset's neighbours in one merge-like walk of this list (sequential
    /// reads) where a hash map took one random probe per site and offset, the larger part of
    /// a rulebook's time on clouds of 10⁵ sites; single lookups bisect it.
    by_key: Vec<(u64, u32)>,
}

/// Why a list of sites is not a sparse grid.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SitesError {
    #[error("site {row} {coord:?} lies outside batch size {batch_size} × grid {shape:?} (z, y, x)")]
    OutOfBounds {
        row: usize,
        coord: [i32; 4],
        batch_size: usize,
        shape: [usize; 3],
    },
    #[error("site {row} {coord:?} repeats row {first}")]
    Duplicate {
        row: usize,
        first: usize,
        coord: [i32; 4],
    },
}

impl SparseSites {
    /// Sites from (batch, z, y, x) rows; refuses a site outside the grid or listed twice
    /// (naming the first row that repeats an earlier one).
    pub fn new(
        coords: Vec<[i32; 4]>,
        spatial_shape: [usize; 3],
        batch_size: usize,
    ) -> Result<SparseSites, SitesError> {
        if coords.len() > u32::MAX as usize {
            // Rows are stored as u32 (as in the rulebooks); a grid this large is refused
            // as out of bounds at its first row past the limit.
            let row = u32::MAX as usize;
            return Err(SitesError::OutOfBounds {
                row,
                coord: coords[row],
                batch_size,
                shape: spatial_shape,
            });
        }
        let mut by_key = Vec::with_capacity(coords.len());
        for (row, &coord) in coords.iter().enumerate() {
            if !in_grid(coord, spatial_shape, batch_size) {
                return Err(SitesError::OutOfBounds {
                    row,
                    coord,
                    batch_size,
                    shape: spatial_shape,
                });
            }
            by_key.push((linear_key(coord, spatial_shape), row as u32));
        }
        // Voxelizers and strided rulebooks mostly list sites in index order already.
        if !by_key.is_sorted() {
            by_key.par_sort_unstable();
        }
        // A repeated index: within a run of equal keys rows ascend, so the run's second
        // entry is its first repeat; the earliest such row over all runs is the one a scan
        // in row order meets first.
        let repeat = by_key
            .windows(2)
            .filter(|w| w[0].0 == w[1].0)
            .min_by_key(|w| w[1].1);
        if let Some(w) = repeat {
            let (first, row) = (w[0].1 as usize, w[1].1 as usize);
            return Err(SitesError::Duplicate {
                row,
                first,
                coord: coords[row],
            });
        }
        Ok(SparseSites {
            coords,
            spatial_shape,
            batch_size,
            by_key,
        })
    }

    /// Sites already in batch-major (b, z, y, x) order, distinct and in bounds (a strided
    /// rulebook's outputs): no sort and no checks beyond debug builds'.
    pub(crate) fn from_sorted(
        coords: Vec<[i32; 4]>,
        spatial_shape: [usize; 3],
        batch_size: usize,
    ) -> SparseSites {
        let by_key: Vec<(u64, u32)> = coords
            .iter()
            .enumerate()
            .map(|(row, &c)| (linear_key(c, spatial_shape), row as u32))
            .collect();
        debug_assert!(by_key.windows(2).all(|w| w[0].0 < w[1].0));
        debug_assert!(
            coords
                .iter()
                .all(|&c| in_grid(c, spatial_shape, batch_size))
        );
        SparseSites {
            coords,
            spatial_shape,
            batch_size,
            by_key,
        }
    }

    pub fn len(&self) -> usize {
        self.coords.len()
    }

    pub fn is_empty(&self) -> bool {
        self.coords.is_empty()
    }

    pub fn coords(&self) -> &[[i32; 4]] {
        &self.coords
    }

    /// [z, y, x] extent of the grid.
    pub fn spatial_shape(&self) -> [usize; 3] {
        self.spatial_shape
    }

    pub fn batch_size(&self) -> usize {
        self.batch_size
    }

    /// (linear index, row) of every site, ascending by index.
    pub(crate) fn by_key(&self) -> &[(u64, u32)] {
        &self.by_key
    }

    /// The row of the site at (batch, z, y, x), if it is active; `None` outside the grid.
    pub fn row(&self, coord: [i32; 4]) -> Option<usize> {
        if !in_grid(coord, self.spatial_shape, self.batch_size) {
            return None;
        }
        let key = linear_key(coord, self.spatial_shape);
        self.by_key
            .binary_search_by_key(&key, |&(k, _)| k)
            .ok()
            .map(|at| self.by_key[at].1 as usize)
    }
}

/// Whether (z, y, x) lies inside `shape` = [z, y, x].
pub(crate) fn in_shape(zyx: [i32; 3], shape: [usize; 3]) -> bool {
    (0..3).all(|a| zyx[a] >= 0 && (zyx[a] as usize) < shape[a])
}

/// Whether (batch, z, y, x) lies inside `batch_size` × `shape`.
fn in_grid(coord: [i32; 4], shape: [usize; 3], batch_size: usize) -> bool {
    coord[0] >= 0
        && (coord[0] as usize) < batch_size
        && in_shape([coord[1], coord[2], coord[3]], shape)
}

/// Batch-major linear index of an in-bounds site.
pub(crate) fn linear_key(coord: [i32; 4], shape: [usize; 3]) -> u64 {
    let [b, z, y, x] = coord.map(|c| c as u64);
    ((b * shape[0] as u64 + z) * shape[1] as u64 + y) * shape[2] as u64 + x
}

/// The site of a linear index ([`linear_key`] inverted).
pub(crate) fn decode_key(key: u64, shape: [usize; 3]) -> [i32; 4] {
    let [z, y, x] = shape.map(|n| n as u64);
    let (rest, cx) = (key / x, key % x);
    let (rest, cy) = (rest / y, rest % y);
    let (b, cz) = (rest / z, rest % z);
    [b, cz, cy, cx].map(|v| v as i32)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn looks_up_rows_and_refuses_bad_sites() {
        let sites =
            SparseSites::new(vec![[0, 1, 2, 3], [1, 1, 2, 3], [0, 0, 0, 0]], [2, 3, 4], 2).unwrap();
        assert_eq!(sites.row([1, 1, 2, 3]), Some(1));
        assert_eq!(sites.row([0, 0, 0, 0]), Some(2));
        assert_eq!(sites.row([0, 0, 0, 1]), None);
        assert_eq!(sites.row([0, 0, 0, 4]), None, "x beyond the grid");
        assert_eq!(sites.row([0, -1, 0, 0]), None);
        assert!(matches!(
            SparseSites::new(vec![[0, 2, 0, 0]], [2, 3, 4], 1),
            Err(SitesError::OutOfBounds { row: 0, .. })
        ));
        assert!(matches!(
            SparseSites::new(vec![[1, 0, 0, 0]], [2, 3, 4], 1),
            Err(SitesError::OutOfBounds { .. })
        ));
        assert_eq!(
            SparseSites::new(vec![[0, 1, 1, 1], [0, 0, 0, 0], [0, 1, 1, 1]], [2, 3, 4], 1)
                .unwrap_err(),
            SitesError::Duplicate {
                row: 2,
                first: 0,
                coord: [0, 1, 1, 1]
            }
        );
    }
}
