//! A cloud's points bucketed by bird's-eye-view cell, so that STCA's crop of a RoI
//! ([`super::stca::RoiPoints`]) tests the points near the RoI instead of the whole cloud.
//!
//! Why: a frame's pseudo cloud holds about 10⁵ points and stage two sees about a hundred
//! RoIs, so testing every point against every rotated box was most of DASANet's RoI stage
//! on the host. The buckets only choose which points are tested; the test itself, and the
//! cloud order the crop keeps, are unchanged, so the crop is the same.

/// Cell edge, metres: a car's RoI (about 4.5 × 2 m with its margin) spans a few cells.
const CELL: f64 = 2.0;
/// Most cells the grid may have; a cloud spread wider gets larger cells.
const MAX_CELLS: usize = 1 << 20;

/// Point indices of a cloud grouped by (x, y) cell, in cloud order within a cell.
#[derive(Debug, Clone)]
pub struct BevBuckets {
    origin: [f64; 2],
    cell: f64,
    dims: [usize; 2],
    /// `starts[c]..starts[c + 1]` index `points` for cell c (row-major, x fastest).
    starts: Vec<u32>,
    points: Vec<u32>,
}

impl BevBuckets {
    /// Buckets the points of `cloud` (`stride` floats each, x and y first); a trailing
    /// partial point is left out, as `chunks_exact` leaves it.
    pub fn new(cloud: &[f32], stride: usize) -> BevBuckets {
        let xy: Vec<[f64; 2]> = cloud
            .chunks_exact(stride)
            .map(|p| [p[0] as f64, p[1] as f64])
            .collect();
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for p in xy.iter().filter(|p| p.iter().all(|v| v.is_finite())) {
            for a in 0..2 {
                lo[a] = lo[a].min(p[a]);
                hi[a] = hi[a].max(p[a]);
            }
        }
        if lo[0] > hi[0] {
            // No finite point: one cell holding every point (each then fails the box test).
            lo = [0.0; 2];
            hi = [0.0; 2];
        }
        let mut cell = CELL;
        let dims = loop {
            let dims = [0, 1].map(|a| ((hi[a] - lo[a]) / cell) as usize + 1);
            if dims[0].saturating_mul(dims[1]) <= MAX_CELLS {
                break dims;
            }
            cell *= 2.0;
        };
        let mut buckets = BevBuckets {
            origin: lo,
            cell,
            dims,
            starts: vec![0; dims[0] * dims[1] + 1],
            points: vec![0; xy.len()],
        };
        let cells: Vec<usize> = xy.iter().map(|p| buckets.cell_of(*p)).collect();
        for &c in &cells {
            buckets.starts[c + 1] += 1;
        }
        for c in 0..dims[0] * dims[1] {
            buckets.starts[c + 1] += buckets.starts[c];
        }
        let mut next = buckets.starts.clone();
        for (i, &c) in cells.iter().enumerate() {
            buckets.points[next[c] as usize] = i as u32;
            next[c] += 1;
        }
        buckets
    }

    /// All `points` points in one cell: every candidate query returns the whole cloud (the
    /// scan the buckets replace, for tests).
    #[cfg(test)]
    pub fn one_cell(points: usize) -> BevBuckets {
        BevBuckets {
            origin: [0.0; 2],
            cell: f64::INFINITY,
            dims: [1, 1],
            starts: vec![0, points as u32],
            points: (0..points as u32).collect(),
        }
    }

    /// The cell of a point, clamped into the grid (a non-finite coordinate lands in cell 0).
    fn cell_of(&self, p: [f64; 2]) -> usize {
        let [ix, iy] = [0, 1].map(|a| self.index(a, p[a]));
        iy * self.dims[0] + ix
    }

    fn index(&self, axis: usize, v: f64) -> usize {
        let i = ((v - self.origin[axis]) / self.cell).floor();
        if i.is_nan() || i < 0.0 {
            0
        } else {
            (i as usize).min(self.dims[axis] - 1)
        }
    }

    /// Indices, ascending, of every point whose (x, y) lies within `[lo, hi]` (each cell
    /// that range touches is taken whole: a superset, never fewer).
    pub fn candidates(&self, lo: [f64; 2], hi: [f64; 2]) -> Vec<u32> {
        let [x0, y0] = [0, 1].map(|a| self.index(a, lo[a]));
        let [x1, y1] = [0, 1].map(|a| self.index(a, hi[a]));
        let mut out = Vec::new();
        for y in y0..=y1 {
            let row = y * self.dims[0];
            let (first, last) = (
                self.starts[row + x0] as usize,
                self.starts[row + x1 + 1] as usize,
            );
            out.extend_from_slice(&self.points[first..last]);
        }
        out.sort_unstable();
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Every point within the range comes back, in cloud order, for ranges inside, across
    /// and beyond the cloud; points with a non-finite coordinate never get lost from the
    /// grid's bookkeeping.
    #[test]
    fn candidates_cover_the_range_in_cloud_order() {
        let mut state = 5u64;
        let mut unit = || {
            state = state
                .wrapping_mul(6_364_136_223_846_793_005)
                .wrapping_add(1_442_695_040_888_963_407);
            (state >> 11) as f64 / (1u64 << 53) as f64
        };
        let mut cloud: Vec<f32> = (0..3000)
            .flat_map(|_| [(unit() * 70.0) as f32, (unit() * 80.0 - 40.0) as f32, 0.5])
            .collect();
        cloud.extend([f32::NAN, 3.0, 0.0, 1.0]);
        let buckets = BevBuckets::new(&cloud, 3);
        assert_eq!(buckets.points.len(), 3001);
        for (lo, hi) in [
            ([10.0, -3.0], [14.5, 1.0]),
            ([-5.0, -50.0], [2.0, -38.0]),
            ([68.0, 39.0], [90.0, 60.0]),
            ([-10.0, -60.0], [100.0, 60.0]),
        ] {
            let got = buckets.candidates(lo, hi);
            assert!(got.windows(2).all(|w| w[0] < w[1]), "ascending");
            let inside = cloud.chunks_exact(3).enumerate().filter(|(_, p)| {
                let (x, y) = (p[0] as f64, p[1] as f64);
                x >= lo[0] && x <= hi[0] && y >= lo[1] && y <= hi[1]
            });
            for (i, _) in inside {
                assert!(got.binary_search(&(i as u32)).is_ok(), "point {i} missed");
            }
        }
    }

    /// A cloud spread far wider than the cell gets coarser cells, not a huge grid.
    #[test]
    fn a_wide_cloud_keeps_the_grid_bounded() {
        let cloud = [0.0f32, 0.0, 1.0e6, 1.0e6];
        let buckets = BevBuckets::new(&cloud, 2);
        assert!(buckets.dims[0] * buckets.dims[1] <= MAX_CELLS);
        assert_eq!(buckets.candidates([-1.0, -1.0], [1.0, 1.0]), vec![0]);
        assert!(
            BevBuckets::new(&[], 4)
                .candidates([0.0; 2], [1.0; 2])
                .is_empty()
        );
    }
}
