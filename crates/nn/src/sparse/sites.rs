//! The active sites of a sparse 3D grid and their hashed lookup.

use rustc_hash::FxHashMap;

/// The active sites of a batch of sparse 3D grids: one row per site, as
/// (batch item, z, y, x), every site inside `spatial_shape` = [z, y, x] and listed once.
/// The row order is the order of the feature rows of every tensor on these sites.
#[derive(Debug, Clone)]
pub struct SparseSites {
    coords: Vec<[i32; 4]>,
    spatial_shape: [usize; 3],
    batch_size: usize,
    /// Linear grid index (batch-major) → row. Fx hashing: the keys are distinct small
    /// integers, which need no protection against adversarial collisions and are hashed
    /// tens of times per site while rulebooks are built.
    rows: FxHashMap<u64, u32>,
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
    /// Sites from (batch, z, y, x) rows; refuses a site outside the grid or listed twice.
    pub fn new(
        coords: Vec<[i32; 4]>,
        spatial_shape: [usize; 3],
        batch_size: usize,
    ) -> Result<SparseSites, SitesError> {
        let mut rows = FxHashMap::with_capacity_and_hasher(coords.len(), Default::default());
        for (row, &coord) in coords.iter().enumerate() {
            let inside = (coord[0] >= 0 && (coord[0] as usize) < batch_size)
                && (0..3).all(|a| coord[a + 1] >= 0 && (coord[a + 1] as usize) < spatial_shape[a]);
            if !inside {
                return Err(SitesError::OutOfBounds {
                    row,
                    coord,
                    batch_size,
                    shape: spatial_shape,
                });
            }
            let key = linear_key(coord, spatial_shape);
            if let Some(&first) = rows.get(&key) {
                return Err(SitesError::Duplicate {
                    row,
                    first: first as usize,
                    coord,
                });
            }
            rows.insert(key, row as u32);
        }
        Ok(SparseSites {
            coords,
            spatial_shape,
            batch_size,
            rows,
        })
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

    /// The row of the site at (batch, z, y, x), if it is active; `None` outside the grid.
    pub fn row(&self, coord: [i32; 4]) -> Option<usize> {
        let inside =
            (0..3).all(|a| coord[a + 1] >= 0 && (coord[a + 1] as usize) < self.spatial_shape[a]);
        if !inside || coord[0] < 0 {
            return None;
        }
        self.rows
            .get(&linear_key(coord, self.spatial_shape))
            .map(|&r| r as usize)
    }
}

/// Batch-major linear index of an in-bounds site.
fn linear_key(coord: [i32; 4], shape: [usize; 3]) -> u64 {
    let [b, z, y, x] = coord.map(|c| c as u64);
    ((b * shape[0] as u64 + z) * shape[1] as u64 + y) * shape[2] as u64 + x
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
