//! From sparse rows back to a dense grid: the height compression that hands a sparse 3D
//! backbone's last map to a 2D bird's-eye-view network.

use super::sites::SparseSites;
use burn::prelude::*;

/// Rows [N, C] on `sites` (grid [Z, Y, X], batch B) → a dense bird's-eye-view map
/// [B, Z·C, Y, X] whose channel `z·C + c` is channel c at height z (zeros where no site
/// is active): the heights stacked into channels, as OpenPCDet's height compression
/// (which orders them `c·Z + z`; the order is a fixed permutation of the next layer's
/// weights and does not change what the network can learn).
///
/// A gather, not a scatter: every cell of the grid reads its site's row or an appended
/// zero row. On the flex backend this runs several times faster than adding the rows
/// into a zero grid, and its gradient is the scatter-add back onto the rows.
pub fn to_dense_bev(features: Tensor<2>, sites: &SparseSites) -> Tensor<4> {
    let [rows, c] = features.dims();
    assert_eq!(rows, sites.len(), "one feature row per site");
    let [z, y, x] = sites.spatial_shape();
    let b = sites.batch_size();
    // Cells of a [B, Y, X, Z] grid, height fastest, each naming its row (or the zero row).
    let mut index = vec![rows as u32; b * y * x * z];
    for (row, s) in sites.coords().iter().enumerate() {
        let [bi, zi, yi, xi] = s.map(|v| v as usize);
        index[((bi * y + yi) * x + xi) * z + zi] = row as u32;
    }
    // On a GPU its backward adds each site's readers in one thread; the empty cells, most
    // of the grid, read the zero row, which no thread walks (`RowGather`).
    crate::gather::RowGather::new(&index, rows, &features.device())
        .gather(features)
        .reshape([b, y, x, z * c])
        .permute([0, 3, 1, 2])
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn stacks_heights_into_channels() {
        let device = Device::flex();
        // Batch 2, grid Z=2, Y=2, X=3, C=2.
        let sites =
            SparseSites::new(vec![[0, 1, 0, 2], [1, 0, 1, 1], [0, 0, 0, 2]], [2, 2, 3], 2).unwrap();
        let rows = Tensor::<2>::from_data(
            TensorData::new(vec![1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0], [3, 2]),
            &device,
        );
        let bev = to_dense_bev(rows, &sites);
        assert_eq!(bev.dims(), [2, 4, 2, 3]);
        let v: Vec<f32> = bev.into_data().try_to_vec::<f32>().unwrap();
        let at = |b: usize, ch: usize, y: usize, x: usize| v[((b * 4 + ch) * 2 + y) * 3 + x];
        // Site 0 (b0, z1, y0, x2): channel c at height 1 → 1·2 + c.
        assert_eq!((at(0, 2, 0, 2), at(0, 3, 0, 2)), (1.0, 2.0));
        // Site 2 (b0, z0, y0, x2) → channels 0 and 1.
        assert_eq!((at(0, 0, 0, 2), at(0, 1, 0, 2)), (5.0, 6.0));
        // Site 1 (b1, z0, y1, x1).
        assert_eq!((at(1, 0, 1, 1), at(1, 1, 1, 1)), (3.0, 4.0));
        assert_eq!(v.iter().filter(|&&a| a != 0.0).count(), 6);
    }
}
