//! The voxel query of RoI grid pooling ([`super::roi_pool`]) as CubeCL kernels, for burn's
//! GPU backends (cargo features `wgpu` and `cuda`): the same scan as the host query — the
//! cube of cells around a grid point's cell in (z, y, x) raster order, the first `samples`
//! active sites whose centres lie within the radius, unfilled slots repeating the first,
//! the sentinel row for none — so the index never leaves the device that pools with it.
//!
//! Why: on a GPU the host query and the upload of its index ([grid points · samples] rows
//! and offsets, megabytes a level) sit between stage one and stage two of every step and
//! frame. Here two kernels replace them: one writes each active site's row into a dense
//! table of the level's cells (the host query's table), one scans per grid point.
//!
//! Layout: the kernels index every input by the strides it comes with. CUDA's allocator
//! pads each row of a 2-D tensor to a power of two of at least 16 bytes ("pitched"), so the
//! grid points [P, 3] arrive four floats a row; wgpu packs them. Kernels that assumed packed
//! rows read other points on CUDA and left rows that were not the host query's (an H200,
//! 2026-11-28: no boxes), where wgpu matched it. The offsets are written to a
//! one-dimensional buffer (which no runtime pads) and relabelled [P · samples, 3]. The
//! kernels are launched unchecked, as burn launches its own: every index is in bounds by
//! construction (the `SAFETY` notes below), so the runtime's bound checks are not needed.
//! On an H200 (2026-11-29) the strided kernels found the host query's rows but at float ties
//! (one grid point of 6,400 with one neighbour in or out at the radius, on 2 of 22 levels
//! checked), and the shipped Voxel R-CNN the host query's boxes; they are the GPUs' query,
//! in inference and in training ([`super::roi_pool::QueryPlace`]).
//!
//! Precision: the host query works in f64; the kernels in f32, on grid points and cell
//! centres measured from the grid's origin (so no 40 m offset eats the mantissa). A
//! neighbour whose squared distance lies within f32 rounding of the squared radius, or a
//! grid point that close to a cell boundary, may be decided the other way; offsets agree
//! within 1e-5 m (tests on wgpu over lavapipe).

use super::roi_pool::{RoiBox, VoxelGeometry, roi_grid_points, scan_reach, stage_stride};
use crate::voxel_rcnn::config::PoolLevelConfig;
use burn::backend::ops::{FloatTensorOps, IntTensorOps};
use burn::backend::tensor::{FloatTensor, IntTensor};
use burn::backend::{Backend, Dispatch, backend_extension};
use burn::prelude::*;
use burn::tensor::{FloatDType, IntDType};
use burn_cubecl::CubeBackend;
use burn_cubecl::tensor::CubeTensor;
pub use fusiondet_nn::cube::cube_runtime;
use fusiondet_nn::cube::{f32_buffer, i32_buffer, launch_shape};
use fusiondet_nn::sparse::SparseSites;
use kernels::{fill_table, scan_neighbours};

/// What the scan of one level needs besides its tensors (all host values).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct LevelQuery {
    /// The level's cell size (x, y, z), metres.
    pub cell: [f32; 3],
    /// The level's grid, [z, y, x] cells.
    pub shape: [u32; 3],
    /// Cells scanned on each side of the grid point's cell, (z, y, x).
    pub reach: [u32; 3],
    pub radius_squared: f32,
    pub samples: u32,
    /// Grid points per RoI (g³).
    pub points_per_roi: u32,
    /// The row an empty neighbourhood reads (the level's site count).
    pub sentinel: u32,
}

/// The query's kernels (see the module's documentation).
#[backend_extension(Cube)]
pub trait VoxelQueryOps: Backend {
    /// From grid points [P, 3] (f32, minus the grid origin), each RoI's batch item [R]
    /// (P = R · points_per_roi) and the level's active sites [N, 4] (b, z, y, x): each
    /// point's `samples` neighbour rows [P · samples] (i32) and neighbour centre minus
    /// point [P · samples, 3].
    fn voxel_query(
        points: FloatTensor<Self>,
        roi_batch: IntTensor<Self>,
        coords: IntTensor<Self>,
        batch_size: usize,
        query: LevelQuery,
    ) -> (IntTensor<Self>, FloatTensor<Self>);
}

/// The kernels, in CubeCL's language (its prelude names `Tensor` and friends apart from
/// burn's).
mod kernels {
    use cubecl::prelude::*;

    /// Writes each site's row at its cell of the dense table ([batch · cells], −1 elsewhere).
    #[cube(launch_unchecked)]
    pub fn fill_table(coords: &Tensor<i32>, table: &mut Tensor<i32>, ny: u32, nx: u32, cells: u32) {
        let row = ABSOLUTE_POS;
        if row >= coords.shape(0) {
            terminate!();
        }
        let at = row * coords.stride(0);
        let step = coords.stride(1);
        let b = u32::cast_from(coords[at]);
        let z = u32::cast_from(coords[at + step]);
        let y = u32::cast_from(coords[at + 2 * step]);
        let x = u32::cast_from(coords[at + 3 * step]);
        let cell = b * cells + (z * ny + y) * nx + x;
        table[cell as usize] = i32::cast_from(row);
    }

    /// One grid point a thread: the raster scan of the host query over the dense table.
    #[cube(launch_unchecked)]
    #[allow(clippy::too_many_arguments)]
    pub fn scan_neighbours(
        points: &Tensor<f32>,
        roi_batch: &Tensor<i32>,
        table: &Tensor<i32>,
        coords: &Tensor<i32>,
        rows: &mut Tensor<i32>,
        offsets: &mut Tensor<f32>,
        cell_x: f32,
        cell_y: f32,
        cell_z: f32,
        nz: u32,
        ny: u32,
        nx: u32,
        reach_z: u32,
        reach_y: u32,
        reach_x: u32,
        radius_squared: f32,
        samples: u32,
        points_per_roi: u32,
        sentinel: u32,
    ) {
        let p = ABSOLUTE_POS;
        if p >= points.shape(0) {
            terminate!();
        }
        let cells = nz * ny * nx;
        let b = u32::cast_from(roi_batch[(p / points_per_roi as usize) * roi_batch.stride(0)]);
        let point = p * points.stride(0);
        let px = points[point];
        let py = points[point + points.stride(1)];
        let pz = points[point + 2 * points.stride(1)];
        let site_stride = coords.stride(0);
        let coord_stride = coords.stride(1);
        let first_z = i32::cast_from((pz / cell_z).floor()) - i32::cast_from(reach_z);
        let first_y = i32::cast_from((py / cell_y).floor()) - i32::cast_from(reach_y);
        let first_x = i32::cast_from((px / cell_x).floor()) - i32::cast_from(reach_x);
        let first_slot = p * samples as usize;
        let mut found = 0u32;
        for iz in 0..2 * reach_z + 1 {
            let z = first_z + i32::cast_from(iz);
            if found < samples && z >= 0 && z < i32::cast_from(nz) {
                for iy in 0..2 * reach_y + 1 {
                    let y = first_y + i32::cast_from(iy);
                    if found < samples && y >= 0 && y < i32::cast_from(ny) {
                        let base = b * cells + (u32::cast_from(z) * ny + u32::cast_from(y)) * nx;
                        for ix in 0..2 * reach_x + 1 {
                            let x = first_x + i32::cast_from(ix);
                            if found < samples && x >= 0 && x < i32::cast_from(nx) {
                                let row = table[(base + u32::cast_from(x)) as usize];
                                if row >= 0 {
                                    let site = usize::cast_from(row) * site_stride;
                                    let ox = (f32::cast_from(coords[site + 3 * coord_stride])
                                        + 0.5)
                                        * cell_x
                                        - px;
                                    let oy = (f32::cast_from(coords[site + 2 * coord_stride])
                                        + 0.5)
                                        * cell_y
                                        - py;
                                    let oz = (f32::cast_from(coords[site + coord_stride]) + 0.5)
                                        * cell_z
                                        - pz;
                                    if ox * ox + oy * oy + oz * oz <= radius_squared {
                                        let slot = first_slot + found as usize;
                                        rows[slot] = row;
                                        offsets[slot * 3] = ox;
                                        offsets[slot * 3 + 1] = oy;
                                        offsets[slot * 3 + 2] = oz;
                                        found += 1;
                                    }
                                }
                            }
                        }
                    }
                }
            }
        }
        // Unfilled slots repeat the first neighbour (a repeat does not change a max); a point
        // with none reads the sentinel row at a zero offset.
        for slot in found..samples {
            let at = first_slot + slot as usize;
            if found > 0 {
                rows[at] = rows[first_slot];
                offsets[at * 3] = offsets[first_slot * 3];
                offsets[at * 3 + 1] = offsets[first_slot * 3 + 1];
                offsets[at * 3 + 2] = offsets[first_slot * 3 + 2];
            } else {
                rows[at] = i32::cast_from(sentinel);
                offsets[at * 3] = 0.0;
                offsets[at * 3 + 1] = 0.0;
                offsets[at * 3 + 2] = 0.0;
            }
        }
    }
}

impl VoxelQueryOps for CubeBackend {
    fn voxel_query(
        points: CubeTensor,
        roi_batch: CubeTensor,
        coords: CubeTensor,
        batch_size: usize,
        query: LevelQuery,
    ) -> (CubeTensor, CubeTensor) {
        let points = Self::float_cast(points, FloatDType::F32);
        let roi_batch = Self::int_cast(roi_batch, IntDType::I32);
        let coords = Self::int_cast(coords, IntDType::I32);
        let client = points.client.clone();
        let device = points.device.clone();
        let [nz, ny, nx] = query.shape;
        let cells = (nz * ny * nx) as usize;
        let table = Self::int_full(
            [batch_size * cells].into(),
            (-1i32).into(),
            &device,
            IntDType::I32,
        );
        let sites = coords.meta.shape()[0];
        if sites > 0 {
            let (count, dim) = launch_shape(&client, sites);
            // SAFETY: every index the kernel forms is in bounds: threads past the last site
            // return first, and a site's (b, z, y, x) lies within the batch and the level's
            // grid (`SparseSites` refuses others), so its cell lies within the table.
            unsafe {
                fill_table::launch_unchecked(
                    &client,
                    count,
                    dim,
                    coords.clone().into_tensor_arg(),
                    table.clone().into_tensor_arg(),
                    ny,
                    nx,
                    nz * ny * nx,
                );
            }
        }
        let num_points = points.meta.shape()[0];
        let slots = num_points * query.samples as usize;
        let rows = i32_buffer(&points, slots);
        // One dimension, so no runtime pads its rows (see the module's documentation); the
        // reshape below only relabels it.
        let offsets = f32_buffer(&points, slots * 3);
        if num_points > 0 {
            let (count, dim) = launch_shape(&client, num_points);
            // SAFETY: threads past the last grid point return first; a point's RoI is in
            // `roi_batch` (points_per_roi points each) and its batch item within the table
            // (`query_level` asserts it); the scanned cells are range-checked against the
            // grid before the table is read; a table entry is −1 or a row of `coords`; the
            // point's `samples` slots are its own.
            unsafe {
                scan_neighbours::launch_unchecked(
                    &client,
                    count,
                    dim,
                    points.into_tensor_arg(),
                    roi_batch.into_tensor_arg(),
                    table.into_tensor_arg(),
                    coords.into_tensor_arg(),
                    rows.clone().into_tensor_arg(),
                    offsets.clone().into_tensor_arg(),
                    query.cell[0],
                    query.cell[1],
                    query.cell[2],
                    nz,
                    ny,
                    nx,
                    query.reach[0],
                    query.reach[1],
                    query.reach[2],
                    query.radius_squared,
                    query.samples,
                    query.points_per_roi,
                    query.sentinel,
                );
            }
        }
        (rows, Self::float_reshape(offsets, [slots, 3].into()))
    }
}

/// The query of every grid point of `rois` (batch item b's RoIs in `rois[b]`, the grid
/// points of [`roi_grid_points`]) at one level, on `device`: neighbour rows [P · samples]
/// and offsets [P · samples, 3], P = Σ RoIs · grid³.
pub fn query_level(
    rois: &[Vec<RoiBox>],
    sites: &SparseSites,
    level: &PoolLevelConfig,
    grid: usize,
    geometry: &VoxelGeometry,
    device: &Device,
) -> (Tensor<1, Int>, Tensor<2>) {
    let device = device.clone().without_autodiff();
    let inputs = LevelInputs::new(rois, sites, level, grid, geometry);
    let num_points = inputs.points.len() / 3;
    let points = Tensor::<2>::from_data(TensorData::new(inputs.points, [num_points, 3]), &device);
    let num_rois = inputs.roi_batch.len();
    let roi_batch =
        Tensor::<1, Int>::from_data(TensorData::new(inputs.roi_batch, [num_rois]), &device);
    let coords =
        Tensor::<2, Int>::from_data(TensorData::new(inputs.coords, [sites.len(), 4]), &device);
    run_query(points, roi_batch, coords, sites.batch_size(), inputs.query)
}

/// The kernels' inputs of one level, packed on the host.
struct LevelInputs {
    /// Grid points minus the grid's origin, [P · 3].
    points: Vec<f32>,
    /// Each RoI's batch item, [R].
    roi_batch: Vec<i32>,
    /// The level's active sites (b, z, y, x), [N · 4].
    coords: Vec<i32>,
    query: LevelQuery,
}

impl LevelInputs {
    fn new(
        rois: &[Vec<RoiBox>],
        sites: &SparseSites,
        level: &PoolLevelConfig,
        grid: usize,
        geometry: &VoxelGeometry,
    ) -> Self {
        // The kernel reads batch item b's table for every RoI of rois[b]: none may lie beyond it.
        assert!(
            rois.len() <= sites.batch_size(),
            "RoIs of {} batch items over sites of {}",
            rois.len(),
            sites.batch_size()
        );
        let size = geometry.level_voxel_size(stage_stride(level.stage));
        let mut points = Vec::new();
        let mut roi_batch = Vec::new();
        for (b, list) in rois.iter().enumerate() {
            for roi in list {
                roi_batch.push(b as i32);
                for p in roi_grid_points(roi, grid) {
                    points.extend((0..3).map(|a| (p[a] - geometry.origin[a]) as f32));
                }
            }
        }
        let [nz, ny, nx] = sites.spatial_shape();
        let query = LevelQuery {
            cell: size.map(|v| v as f32),
            shape: [nz as u32, ny as u32, nx as u32],
            reach: scan_reach(level, size).map(|r| r as u32),
            radius_squared: (level.radius * level.radius) as f32,
            samples: level.samples as u32,
            points_per_roi: (grid * grid * grid) as u32,
            sentinel: sites.len() as u32,
        };
        LevelInputs {
            points,
            roi_batch,
            coords: sites.coords().iter().flatten().copied().collect(),
            query,
        }
    }
}

/// The kernels on tensors already on the device, whatever their strides.
fn run_query(
    points: Tensor<2>,
    roi_batch: Tensor<1, Int>,
    coords: Tensor<2, Int>,
    batch_size: usize,
    query: LevelQuery,
) -> (Tensor<1, Int>, Tensor<2>) {
    let (rows, offsets) = <Dispatch as VoxelQueryOps>::voxel_query(
        points.into_dispatch(),
        roi_batch.into_dispatch(),
        coords.into_dispatch(),
        batch_size,
        query,
    );
    (Tensor::from_dispatch(rows), Tensor::from_dispatch(offsets))
}

#[cfg(all(test, feature = "wgpu"))]
mod tests {
    use super::super::roi_pool::{LevelIndex, RoiGridIndex, RoiGridPool, compare_levels};
    use super::super::synthetic::unit;
    use super::*;
    use crate::voxel_rcnn::backbone3d::SparseMap;
    use crate::voxel_rcnn::config::RoiHeadConfig;
    use std::sync::Arc;

    fn wgpu_device() -> Option<Device> {
        fusiondet_nn::cube::working_wgpu_device("the device query")
    }

    /// A random three-item level with RoIs at random headings, some partly off the grid.
    fn scene() -> (
        Arc<SparseSites>,
        Vec<Vec<RoiBox>>,
        PoolLevelConfig,
        VoxelGeometry,
    ) {
        let mut state = 11u64;
        let (geometry, level) = super::super::roi_pool::test_level();
        let shape = [6, 20, 20];
        let mut coords = std::collections::BTreeSet::new();
        while coords.len() < 600 {
            coords.insert([
                (unit(&mut state) * 2.0) as i32,
                (unit(&mut state) * 6.0) as i32,
                (unit(&mut state) * 20.0) as i32,
                (unit(&mut state) * 20.0) as i32,
            ]);
        }
        let sites = Arc::new(SparseSites::new(coords.into_iter().collect(), shape, 3).unwrap());
        let roi = |state: &mut u64| {
            [
                unit(state) * 4.0,
                unit(state) * 4.0 - 2.0,
                unit(state) * 2.0 - 0.5,
                0.8 + unit(state) * 2.0,
                0.6 + unit(state) * 1.5,
                0.6 + unit(state),
                unit(state) * 6.0 - 3.0,
            ]
        };
        let rois = vec![
            (0..4).map(|_| roi(&mut state)).collect(),
            vec![],
            (0..3).map(|_| roi(&mut state)).collect(),
        ];
        // Item 1 has no RoI; item 2 has no site, so its RoIs find nothing.
        (sites, rois, level, geometry)
    }

    /// How far a grid point is from a decision the f32 kernel could take otherwise: the
    /// smallest gap between a candidate's squared distance and the squared radius, and
    /// between the point and a cell boundary.
    fn margin(
        p: [f64; 3],
        b: usize,
        sites: &SparseSites,
        level: &PoolLevelConfig,
        geometry: &VoxelGeometry,
    ) -> f64 {
        let size = geometry.level_voxel_size(2);
        let rel = [0, 1, 2].map(|a| (p[a] - geometry.origin[a]) / size[a]);
        let mut m = rel
            .iter()
            .zip(size)
            .map(|(r, s)| (r - r.round()).abs() * s)
            .fold(f64::INFINITY, f64::min);
        let r2 = level.radius * level.radius;
        for c in sites.coords().iter().filter(|c| c[0] as usize == b) {
            let centre = geometry.voxel_centre([c[1], c[2], c[3]], 2);
            let d2: f64 = (0..3).map(|a| (centre[a] - p[a]).powi(2)).sum();
            m = m.min((d2 - r2).abs());
        }
        m
    }

    #[test]
    fn the_device_query_finds_the_host_querys_neighbours() {
        let Some(device) = wgpu_device() else { return };
        let (sites, rois, level, geometry) = scene();
        let grid = 3;
        let host = RoiGridIndex::new(
            &rois,
            &[&sites],
            std::slice::from_ref(&level),
            grid,
            &geometry,
        );
        let host = host.levels[0].host().unwrap();
        let (rows, offsets) = query_level(&rois, &sites, &level, grid, &geometry, &device);
        // `FUSIONDET_ROI_QUERY=check`'s comparison sees only the points near a tie differ.
        let index = super::super::roi_pool::DeviceLevelIndex {
            rows: rows.clone(),
            offsets: offsets.clone(),
        };
        let comparison = compare_levels(host, &index, level.samples);
        let rows: Vec<i64> = rows.into_data().convert::<i64>().try_to_vec().unwrap();
        let offsets: Vec<f32> = offsets.into_data().convert::<f32>().try_to_vec().unwrap();
        assert_eq!(rows.len(), host.rows.len());
        let s = level.samples;
        let (mut checked, mut empty) = (0, 0);
        let points = rois.iter().enumerate().flat_map(|(b, list)| {
            list.iter()
                .flat_map(move |r| roi_grid_points(r, grid).into_iter().map(move |p| (b, p)))
        });
        for (i, (b, p)) in points.enumerate() {
            if margin(p, b, &sites, &level, &geometry) < 1e-4 {
                continue;
            }
            checked += 1;
            let slots = i * s..(i + 1) * s;
            assert_eq!(rows[slots.clone()], host.rows[slots.clone()], "point {i}");
            empty += usize::from(host.rows[i * s] == host.sentinel);
            let values = slots.start * 3..slots.end * 3;
            for (a, b) in offsets[values.clone()].iter().zip(&host.offsets[values]) {
                assert!((a - b).abs() < 1e-5, "point {i}: offset {a} vs {b}");
            }
        }
        let total = host.rows.len() / s;
        assert_eq!(comparison.grid_points, total);
        assert!(comparison.differing <= total - checked, "{comparison:?}");
        assert!(comparison.max_offset_difference < 1e-5, "{comparison:?}");
        assert_eq!(comparison.out_of_range, 0, "{comparison:?}");
        assert!(
            checked * 10 >= total * 9,
            "{checked} of {total} points far from a tie"
        );
        assert!(
            empty > 0 && empty < checked,
            "empty and filled neighbourhoods: {empty}"
        );
    }

    /// A row-major [rows, columns] matrix's values in column-major order.
    fn column_major<T: Copy>(values: &[T], columns: usize) -> Vec<T> {
        let rows = values.len() / columns;
        (0..columns)
            .flat_map(|c| (0..rows).map(move |r| values[r * columns + c]))
            .collect()
    }

    /// The kernels index their inputs by the strides they are given: CUDA hands a [P, 3]
    /// tensor over with rows padded to 16 bytes, where wgpu packs them, and kernels that
    /// assumed packed rows read other points there. Inputs laid out column-major here give
    /// the packed upload's rows and offsets bit for bit.
    #[test]
    fn the_kernels_read_inputs_by_their_strides() {
        let Some(device) = wgpu_device() else { return };
        let (sites, rois, level, geometry) = scene();
        let packed = query_level(&rois, &sites, &level, 3, &geometry, &device);
        let inputs = LevelInputs::new(&rois, &sites, &level, 3, &geometry);
        // Transposed views of column-major uploads: the matrices [P, 3] and [N, 4] with
        // strides [1, P] and [1, N].
        let (p, n) = (inputs.points.len() / 3, inputs.coords.len() / 4);
        let points = Tensor::<2>::from_data(
            TensorData::new(column_major(&inputs.points, 3), [3, p]),
            &device,
        )
        .transpose();
        let coords = Tensor::<2, Int>::from_data(
            TensorData::new(column_major(&inputs.coords, 4), [4, n]),
            &device,
        )
        .transpose();
        let roi_batch = Tensor::<1, Int>::from_data(
            TensorData::new(inputs.roi_batch.clone(), [inputs.roi_batch.len()]),
            &device,
        );
        let strided = run_query(points, roi_batch, coords, sites.batch_size(), inputs.query);
        let ints = |t: Tensor<1, Int>| t.into_data().convert::<i64>().try_to_vec::<i64>().unwrap();
        let floats = |t: Tensor<2>| t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap();
        let (rows, offsets) = (ints(packed.0), floats(packed.1));
        assert!(rows.iter().any(|&r| r != i64::from(inputs.query.sentinel)));
        let (strided_rows, strided_offsets) = (ints(strided.0), floats(strided.1));
        let differing = |a: &[i64], b: &[i64]| a.iter().zip(b).filter(|(x, y)| x != y).count();
        assert_eq!(strided_rows.len(), rows.len());
        assert_eq!(
            differing(&strided_rows, &rows),
            0,
            "rows of {} slots differ",
            rows.len()
        );
        assert!(
            strided_offsets
                .iter()
                .map(|v| v.to_bits())
                .eq(offsets.iter().map(|v| v.to_bits())),
            "offsets differ"
        );
    }

    /// RoI grid pooling reads a device index as it reads the host's: the same pooled
    /// features on the same device.
    #[test]
    fn pooling_over_the_device_index_matches_the_host_index() {
        let Some(device) = wgpu_device() else { return };
        let (sites, rois, level, geometry) = scene();
        let grid = 2;
        let channels = 6;
        let mut state = 5u64;
        let feats: Vec<f32> = (0..sites.len() * channels)
            .map(|_| unit(&mut state) as f32 - 0.5)
            .collect();
        let map = SparseMap {
            features: Tensor::from_data(TensorData::new(feats, [sites.len(), channels]), &device),
            sites: sites.clone(),
        };
        let config = RoiHeadConfig {
            grid_size: grid,
            levels: vec![level.clone()],
            ..RoiHeadConfig::default()
        };
        let pool = RoiGridPool::new(&config, &[channels], &device);
        let levels = std::slice::from_ref(&level);
        let host = RoiGridIndex::new(&rois, &[&sites], levels, grid, &geometry);
        let on_device = RoiGridIndex::on_device(&rois, &[&sites], levels, grid, &geometry, &device);
        assert!(matches!(on_device.levels[0], LevelIndex::Device(_)));
        let read = |t: Tensor<2>| t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap();
        let a = read(pool.forward(&[&map], &host));
        let b = read(pool.forward(&[&map], &on_device));
        assert_eq!(a.len(), b.len());
        let worst = a
            .iter()
            .zip(&b)
            .map(|(x, y)| (x - y).abs())
            .fold(0.0, f32::max);
        assert!(worst < 1e-4, "pooled features differ by {worst}");
    }
    /// Through the host's index on a GPU the pooling's gather differentiates by each
    /// voxel's readers (`fusiondet_nn::gather::RowGather`): the pooled features and the
    /// features' gradient are the CPU's within rounding, and so through the device's index,
    /// turned around on the device (training's default).
    #[test]
    fn pooling_gradients_through_the_host_index_match_the_cpu() {
        use crate::device_test_support::{assert_close, upstream};
        let Some(device) = wgpu_device() else { return };
        let (sites, rois, level, geometry) = scene();
        let (grid, channels) = (2, 6);
        let mut state = 7u64;
        let feats: Vec<f32> = (0..sites.len() * channels)
            .map(|_| unit(&mut state) as f32 - 0.5)
            .collect();
        let config = RoiHeadConfig {
            grid_size: grid,
            levels: vec![level.clone()],
            ..RoiHeadConfig::default()
        };
        let cpu = Device::flex().autodiff();
        let pool = RoiGridPool::new(&config, &[channels], &cpu);
        let index = RoiGridIndex::new(
            &rois,
            &[&sites],
            std::slice::from_ref(&level),
            grid,
            &geometry,
        );
        let read = |t: Tensor<2>| t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap();
        let run = |device: &Device, index: &RoiGridIndex| {
            let pool = pool.clone().fork(device);
            let x = Tensor::<2>::from_data(
                TensorData::new(feats.clone(), [sites.len(), channels]),
                device,
            )
            .require_grad();
            let map = SparseMap {
                features: x.clone(),
                sites: sites.clone(),
            };
            let y = pool.forward(&[&map], index);
            let grads = (y.clone() * upstream(y.dims(), device)).sum().backward();
            (read(y), read(x.grad(&grads).unwrap()))
        };
        let want = run(&cpu, &index);
        let gpu = device.autodiff();
        let got = run(&gpu, &index);
        assert_close(&got.0, &want.0, 1e-4, "pooled");
        assert_close(&got.1, &want.1, 1e-4, "gradient");
        assert!(
            want.1.iter().any(|&g| g != 0.0),
            "a gradient reaches the features"
        );
        // Training's default on a GPU: the index made and turned around on the device. Its
        // rows here are the host's (its offsets, taken in f32 from the grid's origin, differ
        // in the last bits), so the CPU's pooled features and gradient within rounding.
        let levels = std::slice::from_ref(&level);
        let on_device = RoiGridIndex::on_device(&rois, &[&sites], levels, grid, &geometry, &gpu);
        let LevelIndex::Device(device_level) = &on_device.levels[0] else {
            panic!("a training device queries on the device");
        };
        let host_level = index.levels[0].host().unwrap();
        assert_eq!(
            compare_levels(host_level, device_level, level.samples).differing,
            0
        );
        let through_device = run(&gpu, &on_device);
        assert_close(&through_device.0, &want.0, 1e-4, "pooled, device index");
        assert_close(&through_device.1, &want.1, 1e-4, "gradient, device index");
    }
}
