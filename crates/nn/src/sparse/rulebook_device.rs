//! A rulebook's kernel map built on the device, for the CubeCL kernels of
//! [`super::device_kernels`] (cargo features `wgpu` and `cuda`).
//!
//! Why: on a GPU machine the rulebooks were the host's largest work of every frame (33 ms
//! of the published Voxel R-CNN's 44 on an H200, 108 ms of DASANet's 163: neighbour walks
//! per offset, then two [rows × volume] tables filled and uploaded). Here the host uploads
//! only the sites (coordinates by row, linear indices ascending with their rows) and one
//! thread per (output row, offset) finds its entry by binary search in the input's indices:
//! output `o` at offset `k` reads the input at `o·s − p + d_k`, or the zero row (`input
//! rows`) where there is none. (The inverse map a backward pass reads is made from this
//! table by the convolution's kernels when one runs.)
//!
//! It is an exact integer search: the same table, entry for entry, as the host's
//! ([`super::rulebook`]'s tests on wgpu compare them). The host still finds a strided
//! layer's output sites (its bitmap, [`super::strided_sites`]): every later stage, the RoI
//! pooling and the BEV map need them on the host anyway.
//!
//! Indices are i32 on the device (what every GPU runtime has): a grid whose batch holds
//! more than 2³¹ − 1 cells (a thousand KITTI grids at the published voxel size) is built on
//! the host instead.

use super::rulebook::ConvGeometry;
use super::sites::SparseSites;
use crate::cube::{i32_buffer, launch_shape};
use burn::backend::Autodiff;
use burn::backend::autodiff::checkpoint::strategy::CheckpointStrategy;
use burn::backend::ops::IntTensorOps;
use burn::backend::tensor::IntTensor;
use burn::backend::{Backend, Dispatch, backend_extension};
use burn::prelude::*;
use burn::tensor::IntDType;
use burn_cubecl::CubeBackend;
use burn_cubecl::tensor::CubeTensor;

/// The search (see the module's documentation).
#[backend_extension(Cube, Autodiff)]
pub trait KernelMapSearchOps: Backend {
    /// For every row r of `from` [rows · 4] (batch, z, y, x) and offset k of `volume`: the
    /// row of the `to` site it reads (`to_keys` [sites] its linear indices ascending,
    /// `to_rows` [sites] their rows), or the number of `to` sites (the zero row the table
    /// names for none), at `r · volume + k` of the result.
    /// `geometry` [12] holds the kernel, stride and padding (z, y, x) and the `to` grid's
    /// extent.
    fn kernel_map_search(
        from: IntTensor<Self>,
        to_keys: IntTensor<Self>,
        to_rows: IntTensor<Self>,
        geometry: IntTensor<Self>,
        volume: usize,
    ) -> IntTensor<Self>;
}

mod kernels {
    use cubecl::prelude::*;

    /// The coordinate along one axis that `c` reads at kernel offset `d`, `c·s − p + d`, or
    /// −1 outside `0..extent`.
    #[cube]
    fn reach(c: i32, d: i32, s: i32, p: i32, extent: i32) -> i32 {
        let at = c * s - p + d;
        select(at >= 0 && at < extent, at, -1i32)
    }

    /// One (row, offset) a thread: `out[r · volume + k]`.
    #[cube(launch_unchecked)]
    pub fn search(
        from: &Tensor<i32>,
        keys: &Tensor<i32>,
        rows: &Tensor<i32>,
        g: &Tensor<i32>,
        out: &mut Tensor<i32>,
        volume: u32,
    ) {
        let unit = ABSOLUTE_POS;
        if unit >= out.shape(0) {
            terminate!();
        }
        let r = unit / volume as usize;
        let k = i32::cast_from(unit % volume as usize);
        let (ky, kx) = (g[1], g[2]);
        let (dz, dy, dx) = (k / (ky * kx), (k / kx) % ky, k % kx);
        let (ez, ey, ex) = (g[9], g[10], g[11]);
        let b = from[r * 4];
        let z = reach(from[r * 4 + 1], dz, g[3], g[6], ez);
        let y = reach(from[r * 4 + 2], dy, g[4], g[7], ey);
        let x = reach(from[r * 4 + 3], dx, g[5], g[8], ex);
        // None: the zero row appended after the sites' rows.
        let mut value = i32::cast_from(keys.shape(0));
        if z >= 0 && y >= 0 && x >= 0 {
            let key = ((b * ez + z) * ey + y) * ex + x;
            // The first index not below `key`.
            let len = keys.shape(0);
            let mut lo = 0usize;
            let mut hi = len;
            while lo < hi {
                let mid = (lo + hi) / 2;
                if keys[mid] < key {
                    lo = mid + 1;
                } else {
                    hi = mid;
                }
            }
            // Nested, not `&&`: a kernel evaluates both sides, and `keys[len]` is past the end.
            #[allow(clippy::collapsible_if)]
            if lo < len {
                if keys[lo] == key {
                    value = rows[lo];
                }
            }
        }
        out[unit] = value;
    }
}

fn search(
    from: CubeTensor,
    keys: CubeTensor,
    rows: CubeTensor,
    geometry: CubeTensor,
    volume: usize,
) -> CubeTensor {
    let cast = |t: CubeTensor| CubeBackend::int_cast(t, IntDType::I32);
    let (from, keys, rows, geometry) = (cast(from), cast(keys), cast(rows), cast(geometry));
    let units = from.meta.shape()[0] / 4 * volume;
    let out = i32_buffer(&from, units);
    if units > 0 {
        let client = from.client.clone();
        let (count, dim) = launch_shape(&client, units);
        // SAFETY: threads past the last entry return first; row r < rows reads `from` at
        // r · 4 + 3 < rows · 4; the geometry has its 12 values; the search's indices stay
        // below the keys' length, and `rows` has one per key. (All tensors here are
        // one-dimensional and made contiguous by the upload or the cast.)
        unsafe {
            kernels::search::launch_unchecked(
                &client,
                count,
                dim,
                from.into_tensor_arg(),
                keys.into_tensor_arg(),
                rows.into_tensor_arg(),
                geometry.into_tensor_arg(),
                out.clone().into_tensor_arg(),
                volume as u32,
            );
        }
    }
    out
}

impl KernelMapSearchOps for CubeBackend {
    fn kernel_map_search(
        from: CubeTensor,
        to_keys: CubeTensor,
        to_rows: CubeTensor,
        geometry: CubeTensor,
        volume: usize,
    ) -> CubeTensor {
        search(from, to_keys, to_rows, geometry, volume)
    }
}

/// Integer tensors have no autodiff graph: the same search.
impl<C: CheckpointStrategy> KernelMapSearchOps for Autodiff<CubeBackend, C> {
    fn kernel_map_search(
        from: IntTensor<Self>,
        to_keys: IntTensor<Self>,
        to_rows: IntTensor<Self>,
        geometry: IntTensor<Self>,
        volume: usize,
    ) -> IntTensor<Self> {
        search(from, to_keys, to_rows, geometry, volume)
    }
}

/// Whether every linear index of `sites`' batch of grids fits an i32.
fn fits_i32(sites: &SparseSites) -> bool {
    let cells =
        sites.batch_size() as u128 * sites.spatial_shape().iter().product::<usize>() as u128;
    cells <= i32::MAX as u128
}

/// The kernel map [output rows · volume] of a layer of `geometry` from `input` to `output`
/// sites (`None`: a submanifold layer's, onto its inputs), built on `device` (a CubeCL
/// device); `None` where the input grids' indices, which the search compares, do not fit an
/// i32.
pub(crate) fn kernel_map(
    input: &SparseSites,
    output: Option<&SparseSites>,
    geometry: &ConvGeometry,
    device: &Device,
) -> Option<Tensor<1, Int>> {
    if !fits_i32(input) {
        return None;
    }
    let int = |values: Vec<i32>| {
        let len = values.len();
        Tensor::<1, Int>::from_data(TensorData::new(values, [len]), device)
    };
    let geometry_values: Vec<i32> = [
        geometry.kernel,
        geometry.stride,
        geometry.padding,
        input.spatial_shape(),
    ]
    .iter()
    .flatten()
    .map(|&v| v as i32)
    .collect();
    // The output sites' coordinates by row [rows · 4]; the input's linear indices ascending
    // and the row of each.
    let from: Vec<i32> = output
        .unwrap_or(input)
        .coords()
        .iter()
        .flatten()
        .copied()
        .collect();
    let (keys, rows): (Vec<i32>, Vec<i32>) = input
        .by_key()
        .iter()
        .map(|&(key, row)| (key as i32, row as i32))
        .unzip();
    Some(Tensor::from_dispatch(
        <Dispatch as KernelMapSearchOps>::kernel_map_search(
            int(from).into_dispatch(),
            int(keys).into_dispatch(),
            int(rows).into_dispatch(),
            int(geometry_values).into_dispatch(),
            geometry.volume(),
        ),
    ))
}

#[cfg(all(test, feature = "wgpu"))]
mod tests {
    use super::super::rulebook::{ConvGeometry, RuleGather, RuleLayout, Rulebook, TableBuild};
    use super::super::sites::SparseSites;
    use super::super::test_data::{ints, sites};
    use crate::cube::working_wgpu_device;
    use burn::prelude::*;
    use std::sync::Arc;

    /// The table of a rulebook in the kernels' layout.
    fn table(book: &Rulebook) -> Vec<i64> {
        match &book.gather {
            RuleGather::KernelMap {
                table,
                kernels: true,
            } => ints(table),
            _ => panic!("the kernels' layout"),
        }
    }

    fn build(
        sites: &Arc<SparseSites>,
        geometry: ConvGeometry,
        same: bool,
        on: TableBuild,
        device: &Device,
    ) -> Rulebook {
        if same {
            Rulebook::submanifold_built(
                sites,
                geometry.kernel,
                RuleLayout::DeviceKernels,
                device,
                on,
            )
        } else {
            Rulebook::strided_built(sites, geometry, RuleLayout::DeviceKernels, device, on)
        }
    }

    /// The device's search gives the host's table entry for entry, and the same pair
    /// counts, for submanifold and strided geometries (the backbones' and odd ones) over two
    /// batch items, with sites dense enough to touch every edge of the grid and so sparse
    /// most offsets are empty; and over no sites.
    #[test]
    fn device_tables_equal_the_hosts() {
        let Some(gpu) = working_wgpu_device("the rulebook search kernel") else {
            return;
        };
        let cases = [
            (ConvGeometry::same([3; 3]), true),
            (ConvGeometry::same([1, 3, 5]), true),
            (ConvGeometry::strided([3; 3], [2; 3], [1; 3]), false),
            (ConvGeometry::strided([3; 3], [2; 3], [0, 1, 1]), false),
            (ConvGeometry::strided([3, 1, 1], [2, 1, 1], [0; 3]), false),
            (
                ConvGeometry::strided([2, 3, 3], [1, 2, 2], [0, 1, 1]),
                false,
            ),
        ];
        for (shape, count, seed) in [
            ([5, 9, 7], 200, 1),
            ([30, 40, 50], 300, 2),
            ([1, 4, 30], 100, 3),
        ] {
            let sites = sites(shape, count, seed);
            for (geometry, same) in cases {
                let host = build(&sites, geometry, same, TableBuild::Host, &gpu);
                let device = build(&sites, geometry, same, TableBuild::Device, &gpu);
                assert_eq!(device.output.coords(), host.output.coords());
                assert_eq!(table(&device), table(&host), "{geometry:?} on {shape:?}");
                assert_eq!(
                    device.total_pairs(),
                    host.total_pairs(),
                    "{geometry:?} on {shape:?}"
                );
            }
        }
        let empty = Arc::new(SparseSites::new(Vec::new(), [4, 4, 4], 1).unwrap());
        let book = build(
            &empty,
            ConvGeometry::same([3; 3]),
            true,
            TableBuild::Device,
            &gpu,
        );
        assert!(table(&book).is_empty());
        assert_eq!(book.total_pairs(), 0);
    }
}
