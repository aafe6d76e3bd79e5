//! Voxel RoI pooling (Voxel R-CNN, Section 3.2): a 6 × 6 × 6 grid of points inside each
//! RoI gathers, at several backbone levels, the voxels around it. The neighbours of a
//! grid point are found by a voxel query — the cube of ±`query_range` voxels around the
//! grid point's voxel, scanned in (z, y, x) raster order, keeping the voxels whose centres
//! lie within `radius`, the first `samples` of them (OpenPCDet's order). Per level:
//! features through a linear layer + BN, relative positions through another, summed,
//! ReLU, max over the neighbours, a linear layer + BN + ReLU.
//!
//! The query is index work ([`RoiGridIndex`]): on the host for the CPU device, as CubeCL
//! kernels on burn's GPU backends (`roi_query_device`, cargo features `wgpu` / `cuda`).
//! The network part ([`RoiGridPool`]) gathers with the index, so gradients reach the
//! backbone.

use super::backbone3d::SparseMap;
use super::config::{HEAD_NORM, PoolLevelConfig, RoiHeadConfig};
use burn::nn::{BatchNorm, Linear, LinearConfig};
use burn::prelude::*;
use burn::tensor::activation::relu;
use fusiondet_nn::gather::RowGather;
use fusiondet_nn::place::Place;
use fusiondet_nn::ragged::{self, Neighbours, Runs};
use fusiondet_nn::sparse::SparseSites;
use fusiondet_nn::{batch_norm, norm_rows, norm_rows_relu};
use rayon::prelude::*;
use std::sync::Arc;

/// A RoI in the LiDAR frame: centre (x, y, z), sizes (dx, dy, dz), heading about +z.
pub type RoiBox = [f64; 7];

/// Where voxel (z, y, x) of a map lies: the voxel grid's origin (the point range's
/// minimum corner) and the voxel size at that map's stride, in metres.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct VoxelGeometry {
    pub origin: [f64; 3],
    /// Input voxel size (x, y, z).
    pub voxel_size: [f64; 3],
}

impl VoxelGeometry {
    /// Voxel size of a map downsampled `stride` times (OpenPCDet uses the nominal stride
    /// on every axis, also where a stage's padding makes the z grid not divide exactly).
    pub fn level_voxel_size(&self, stride: usize) -> [f64; 3] {
        self.voxel_size.map(|v| v * stride as f64)
    }

    /// Centre of voxel `[z, y, x]` of a map at `stride`, as (x, y, z).
    pub fn voxel_centre(&self, coord: [i32; 3], stride: usize) -> [f64; 3] {
        let size = self.level_voxel_size(stride);
        let [z, y, x] = coord;
        [
            (x as f64 + 0.5) * size[0] + self.origin[0],
            (y as f64 + 0.5) * size[1] + self.origin[1],
            (z as f64 + 0.5) * size[2] + self.origin[2],
        ]
    }
}

/// The grid points of a RoI, (x, y, z), x index outermost: cell centres of a g × g × g
/// split of the box, rotated by its heading.
pub fn roi_grid_points(roi: &RoiBox, grid: usize) -> Vec<[f64; 3]> {
    let [cx, cy, cz, dx, dy, dz, heading] = *roi;
    let (sin, cos) = heading.sin_cos();
    let local = |i: usize, d: f64| ((i as f64 + 0.5) / grid as f64 - 0.5) * d;
    let mut points = Vec::with_capacity(grid * grid * grid);
    for i in 0..grid {
        for j in 0..grid {
            for k in 0..grid {
                let (lx, ly, lz) = (local(i, dx), local(j, dy), local(k, dz));
                points.push([cx + lx * cos - ly * sin, cy + lx * sin + ly * cos, cz + lz]);
            }
        }
    }
    points
}

/// The neighbour index of every grid point at one level, where it was made.
#[derive(Debug, Clone)]
pub enum LevelIndex {
    /// By the host query (the CPU, training on a GPU, or `FUSIONDET_ROI_QUERY=host`;
    /// [`QueryPlace`]).
    Host(HostLevelIndex),
    /// By the device's kernels, on the device.
    Device(Box<DeviceLevelIndex>),
}

/// The device query's neighbour index of every grid point at one level, on the device.
#[derive(Debug, Clone)]
pub struct DeviceLevelIndex {
    /// [grid points · samples] rows into the level's features; the level's row count (the
    /// host's sentinel, a zero row appended by the network) for a grid point with none.
    pub rows: Tensor<1, Int>,
    /// [grid points · samples, 3] neighbour centre minus grid point (zero for none).
    pub offsets: Tensor<2>,
}

impl LevelIndex {
    /// The host query's index; `None` for one made on the device.
    pub fn host(&self) -> Option<&HostLevelIndex> {
        match self {
            LevelIndex::Host(level) => Some(level),
            LevelIndex::Device(_) => None,
        }
    }
}

/// The host query's neighbour index of every grid point at one level.
#[derive(Debug, Clone)]
pub struct HostLevelIndex {
    /// [grid points · samples] rows into the level's features; `sentinel` (= the row
    /// count, a zero row appended by the network) for a grid point with no neighbour.
    pub rows: Vec<i64>,
    /// [grid points · samples · 3] neighbour centre minus grid point (zero for none), f32.
    pub offsets: Vec<f32>,
    pub sentinel: i64,
    /// Grid points that found no neighbour (diagnostics).
    pub empty: usize,
}

impl HostLevelIndex {
    /// `offsets` as a [grid points · samples, 3] tensor on `device`.
    fn offsets_tensor(&self, device: &Device) -> Tensor<2> {
        let rows = self.offsets.len() / 3;
        Tensor::from_data(TensorData::new(self.offsets.clone(), [rows, 3]), device)
    }
}

/// Grid points of all RoIs of a batch and their neighbours at every pooling level.
#[derive(Debug, Clone)]
pub struct RoiGridIndex {
    pub num_rois: usize,
    pub points_per_roi: usize,
    pub levels: Vec<LevelIndex>,
}

/// Backbone stride of stage `stage` (1–4).
pub fn stage_stride(stage: usize) -> usize {
    1 << (stage - 1)
}

impl RoiGridIndex {
    /// `rois[b]` are the RoIs of batch item b; `sites[l]` the active sites of level l's
    /// stage; `levels` their settings.
    pub fn new(
        rois: &[Vec<RoiBox>],
        sites: &[&SparseSites],
        levels: &[PoolLevelConfig],
        grid: usize,
        geometry: &VoxelGeometry,
    ) -> RoiGridIndex {
        let points: Vec<(usize, [f64; 3])> = rois
            .iter()
            .enumerate()
            .flat_map(|(b, list)| {
                list.iter()
                    .flat_map(move |r| roi_grid_points(r, grid).into_iter().map(move |p| (b, p)))
            })
            .collect();
        let levels = levels
            .iter()
            .zip(sites)
            .map(|(level, sites)| LevelIndex::Host(query_level(&points, sites, level, geometry)))
            .collect();
        Self::with_levels(rois, grid, levels)
    }

    /// The index of `rois` at `grid`³ points each, over the levels' neighbours.
    fn with_levels(rois: &[Vec<RoiBox>], grid: usize, levels: Vec<LevelIndex>) -> RoiGridIndex {
        RoiGridIndex {
            num_rois: rois.iter().map(Vec::len).sum(),
            points_per_roi: grid * grid * grid,
            levels,
        }
    }

    /// The query where the network runs on `device`, as [`query_place`] decides:
    /// the device's kernels, the host query ([`Self::new`]), or both compared
    /// (`FUSIONDET_ROI_QUERY=check`: the host's index is used, each difference reported).
    pub fn on_device(
        rois: &[Vec<RoiBox>],
        sites: &[&SparseSites],
        levels: &[PoolLevelConfig],
        grid: usize,
        geometry: &VoxelGeometry,
        device: &Device,
    ) -> RoiGridIndex {
        #[cfg(any(feature = "wgpu", feature = "cuda"))]
        {
            let place = query_place(device);
            if place != QueryPlace::Host {
                let on_device = levels
                    .iter()
                    .zip(sites)
                    .map(|(level, sites)| {
                        let (rows, offsets) = super::roi_query_device::query_level(
                            rois, sites, level, grid, geometry, device,
                        );
                        DeviceLevelIndex { rows, offsets }
                    })
                    .collect::<Vec<_>>();
                if place == QueryPlace::Device {
                    let levels = on_device
                        .into_iter()
                        .map(|level| LevelIndex::Device(Box::new(level)))
                        .collect();
                    return Self::with_levels(rois, grid, levels);
                }
                let host = Self::new(rois, sites, levels, grid, geometry);
                for (l, (host_level, device_level)) in
                    host.levels.iter().zip(&on_device).enumerate()
                {
                    if let Some(host_level) = host_level.host() {
                        report_check(
                            l,
                            &compare_levels(host_level, device_level, levels[l].samples),
                        );
                    }
                }
                return host;
            }
        }
        let _ = device;
        Self::new(rois, sites, levels, grid, geometry)
    }
}

/// Where the RoI grid query runs: the host query, its index uploaded; the device's kernels
/// ([`super::roi_query_device`]); or both, the host's index used and the device's compared
/// with it.
pub type QueryPlace = Place;

/// Where the RoI grid query runs on `device`: the host on the CPU; on a CubeCL device
/// `FUSIONDET_ROI_QUERY` (`host`, `device` or `check`) where set, else the device's kernels.
///
/// In inference the kernels took the shipped Voxel R-CNN from 35 to 50 frames/s on an
/// H200 (2026-11-29), with the host query's boxes (111 of 111 paired within 0.01 m);
/// `check` there found only grid points at float ties with other rows (2 of 22 levels).
/// In training the pooling's gather is differentiated through the index turned around on
/// the device ([`fusiondet_nn::gather::RowGather::from_device_index`]), as the host
/// index's is on the host, so no step waits for the host query (about 0.06 s of a
/// published Voxel R-CNN step on that machine's 16 cores) and its upload.
pub fn query_place(device: &Device) -> QueryPlace {
    static READ: std::sync::OnceLock<Option<Place>> = std::sync::OnceLock::new();
    Place::for_device(device, "FUSIONDET_ROI_QUERY", &READ)
}

/// How the device's index of one level compares with the host's.
#[derive(Debug, Clone, PartialEq)]
pub struct LevelComparison {
    pub grid_points: usize,
    /// Grid points whose neighbour rows differ (the same rows in the same order agree).
    pub differing: usize,
    /// The first of them: (grid point, host rows, device rows).
    pub first: Option<(usize, Vec<i64>, Vec<i64>)>,
    /// The largest offset difference where the rows agree, metres.
    pub max_offset_difference: f32,
    /// Device rows outside 0..=sentinel (what no query writes: a kernel that did not run,
    /// or wrote elsewhere, leaves such values).
    pub out_of_range: usize,
}

/// Compares the device's index of a level with the host's, grid point by grid point
/// (`samples` rows each). Reads the device's index back: for diagnostics only.
pub fn compare_levels(
    host: &HostLevelIndex,
    device: &DeviceLevelIndex,
    samples: usize,
) -> LevelComparison {
    let rows: Vec<i64> = device
        .rows
        .clone()
        .into_data()
        .try_into_vec_as::<i64>()
        .expect("integer rows");
    let offsets: Vec<f32> = device
        .offsets
        .clone()
        .into_data()
        .try_into_vec_as::<f32>()
        .expect("f32 offsets");
    let grid_points = host.rows.len() / samples.max(1);
    let mut comparison = LevelComparison {
        grid_points,
        differing: 0,
        first: None,
        max_offset_difference: 0.0,
        out_of_range: rows
            .iter()
            .filter(|&&r| !(0..=host.sentinel).contains(&r))
            .count(),
    };
    if rows.len() != host.rows.len() || offsets.len() != host.offsets.len() {
        comparison.differing = grid_points;
        comparison.first = Some((0, host.rows.clone(), rows));
        return comparison;
    }
    for p in 0..grid_points {
        let slots = p * samples..(p + 1) * samples;
        if host.rows[slots.clone()] != rows[slots.clone()] {
            comparison.differing += 1;
            if comparison.first.is_none() {
                comparison.first =
                    Some((p, host.rows[slots.clone()].to_vec(), rows[slots].to_vec()));
            }
            continue;
        }
        let values = slots.start * 3..slots.end * 3;
        for (h, d) in host.offsets[values.clone()].iter().zip(&offsets[values]) {
            comparison.max_offset_difference = comparison.max_offset_difference.max((h - d).abs());
        }
    }
    comparison
}

/// One line on stderr per level checked (`FUSIONDET_ROI_QUERY=check`), the first 20 of a
/// process in full, then only levels that differ.
#[cfg(any(feature = "wgpu", feature = "cuda"))]
fn report_check(level: usize, c: &LevelComparison) {
    use std::sync::atomic::{AtomicUsize, Ordering};
    static REPORTED: AtomicUsize = AtomicUsize::new(0);
    let n = REPORTED.fetch_add(1, Ordering::Relaxed);
    if n >= 20 && c.differing == 0 {
        return;
    }
    let first = match &c.first {
        Some((p, host, device)) => {
            format!("; first at grid point {p}: host rows {host:?}, device rows {device:?}")
        }
        None => String::new(),
    };
    eprintln!(
        "RoI query check, level {level}: {} of {} grid points with other rows on the device, \
         offsets within {:.1e} m where the rows agree, {} rows out of range{first}",
        c.differing, c.grid_points, c.max_offset_difference, c.out_of_range
    );
}

/// Cells scanned on each side of a grid point's cell, (z, y, x), at a level of cell size
/// `size` (x, y, z): the query range, less where cells farther than the radius along an axis
/// cannot hold a neighbour (the host query and the device's scan the same cells).
pub(super) fn scan_reach(level: &PoolLevelConfig, size: [f64; 3]) -> [usize; 3] {
    std::array::from_fn(|a| {
        let axis_size = [size[2], size[1], size[0]][a];
        level.query_range[a].min((level.radius / axis_size).floor() as usize + 1)
    })
}

/// The dense cell tables of [`query_level`]: each cell's row (−1 where none) and a bit a cell,
/// set where a row is. One set is kept for the process between queries, all empty between
/// them (one, not one a thread: a table of a published level is tens of megabytes).
struct CellTable {
    rows: Vec<i32>,
    occupied: Vec<u64>,
}

impl CellTable {
    const fn empty() -> Self {
        CellTable {
            rows: Vec::new(),
            occupied: Vec::new(),
        }
    }
}

static CELL_TABLE: std::sync::Mutex<CellTable> = std::sync::Mutex::new(CellTable::empty());

/// One query's view of the kept tables (see [`with_cell_table`]).
struct Cells<'a> {
    rows: &'a [i32],
    occupied: &'a [u64],
}

impl Cells<'_> {
    /// `visit(row)` for every occupied cell of `first..=last`, ascending, until it returns
    /// false (then false). Empty cells cost a bit each, not a read of the row table.
    fn each_occupied(&self, first: usize, last: usize, mut visit: impl FnMut(i32) -> bool) -> bool {
        for word in first / 64..=last / 64 {
            let low = if word == first / 64 { first % 64 } else { 0 };
            let high = if word == last / 64 { last % 64 } else { 63 };
            let mask = (u64::MAX >> (63 - high)) & (u64::MAX << low);
            let mut bits = self.occupied[word] & mask;
            while bits != 0 {
                let cell = word * 64 + bits.trailing_zeros() as usize;
                if !visit(self.rows[cell]) {
                    return false;
                }
                bits &= bits - 1;
            }
        }
        true
    }
}

/// `query(cells)` over dense tables of `cells` cells holding each of `sites`' rows at its
/// cell (linear index by [`SparseSites`]' batch-major layout) and nothing elsewhere.
///
/// Why kept: a published level is tens of millions of cells (stage 2 of the KITTI grid,
/// [21, 800, 704], is 11.8 M a frame: 95 MB of i32 for a batch of two), and allocating and
/// filling it anew for every query was a serial pass and a page fault per 4 KiB on each
/// training step and each detected frame, beside a parallel query of a few milliseconds. The
/// tables stay (the largest level's size), and only the sites' cells are written and cleared
/// per query. The bit a cell lets the scan pass over empty cells (most
/// of a grid point's neighbourhood) without reading the row table.
fn with_cell_table<R>(
    cells: usize,
    sites: impl Iterator<Item = (usize, i32)> + Clone,
    query: impl FnOnce(Cells<'_>) -> R,
) -> R {
    // A query that panicked left the tables cleared (its guard ran), so a poisoned lock's
    // tables are good; a second query at the same time builds tables of its own.
    match CELL_TABLE.try_lock() {
        Ok(mut kept) => with_cells_in(&mut kept, cells, sites, query),
        Err(std::sync::TryLockError::Poisoned(poisoned)) => {
            with_cells_in(&mut poisoned.into_inner(), cells, sites, query)
        }
        Err(std::sync::TryLockError::WouldBlock) => {
            with_cells_in(&mut CellTable::empty(), cells, sites, query)
        }
    }
}

/// [`with_cell_table`] on the tables `table` (empty before, empty after).
fn with_cells_in<R>(
    table: &mut CellTable,
    cells: usize,
    sites: impl Iterator<Item = (usize, i32)> + Clone,
    query: impl FnOnce(Cells<'_>) -> R,
) -> R {
    /// Clears the cells it set, also when the query panics, so that the tables stay empty.
    struct Cleared<'a, I: Iterator<Item = (usize, i32)> + Clone> {
        table: &'a mut CellTable,
        sites: I,
    }
    impl<I: Iterator<Item = (usize, i32)> + Clone> Drop for Cleared<'_, I> {
        fn drop(&mut self) {
            for (cell, _) in self.sites.clone() {
                self.table.rows[cell] = -1;
                self.table.occupied[cell / 64] &= !(1u64 << (cell % 64));
            }
        }
    }
    if table.rows.len() < cells {
        table.rows.resize(cells, -1);
        table.occupied.resize(cells.div_ceil(64), 0);
    }
    for (cell, row) in sites.clone() {
        table.rows[cell] = row;
        table.occupied[cell / 64] |= 1u64 << (cell % 64);
    }
    let guard = Cleared { table, sites };
    query(Cells {
        rows: &guard.table.rows[..cells],
        occupied: &guard.table.occupied[..cells.div_ceil(64)],
    })
}

/// The voxel query of every grid point at one level, over a dense lookup table of the
/// level's active sites (a table read per visited cell is several times faster than a
/// hash lookup, and a level's grid is at most tens of millions of cells).
fn query_level(
    points: &[(usize, [f64; 3])],
    sites: &SparseSites,
    level: &PoolLevelConfig,
    geometry: &VoxelGeometry,
) -> HostLevelIndex {
    let (cells, site_cells) = cells_of(sites);
    with_cell_table(cells, site_cells, |table| {
        query_level_in(points, sites, level, geometry, table)
    })
}

/// The tables' size for `sites` (every batch item's grid) and each site's (cell, row).
fn cells_of(sites: &SparseSites) -> (usize, impl Iterator<Item = (usize, i32)> + Clone + '_) {
    let [nz, ny, nx] = sites.spatial_shape();
    let cells = nz * ny * nx;
    let site_cells = sites.coords().iter().enumerate().map(move |(row, c)| {
        let [b, z, y, x] = c.map(|v| v as usize);
        (b * cells + (z * ny + y) * nx + x, row as i32)
    });
    (sites.batch_size() * cells, site_cells)
}

/// [`query_level`] over the tables `table` instead of the kept ones (the tests').
#[cfg(test)]
fn query_level_with(
    table: &mut CellTable,
    points: &[(usize, [f64; 3])],
    sites: &SparseSites,
    level: &PoolLevelConfig,
    geometry: &VoxelGeometry,
) -> HostLevelIndex {
    let (cells, site_cells) = cells_of(sites);
    with_cells_in(table, cells, site_cells, |table| {
        query_level_in(points, sites, level, geometry, table)
    })
}

/// [`query_level`] given its table.
fn query_level_in(
    points: &[(usize, [f64; 3])],
    sites: &SparseSites,
    level: &PoolLevelConfig,
    geometry: &VoxelGeometry,
    table: Cells<'_>,
) -> HostLevelIndex {
    let [nz, ny, nx] = sites.spatial_shape();
    let stride = stage_stride(level.stage);
    let size = geometry.level_voxel_size(stride);
    let cells = nz * ny * nx;
    let centres: Vec<[f64; 3]> = sites
        .coords()
        .iter()
        .map(|c| geometry.voxel_centre([c[1], c[2], c[3]], stride))
        .collect();
    let r2 = level.radius * level.radius;
    // Cells farther than the radius along an axis cannot hold a neighbour: skip them.
    let reach = scan_reach(level, size).map(|r| r as i64);
    let sentinel = sites.len() as i64;
    let s = level.samples;
    // Each grid point writes its own s rows and 3s offsets in place (no per-point vectors
    // gathered and copied together after, which was a serial pass over every output).
    let mut rows = vec![0i64; points.len() * s];
    let mut offsets = vec![0f32; points.len() * s * 3];
    rows.par_chunks_mut(s.max(1))
        .zip(offsets.par_chunks_mut(3 * s.max(1)))
        .zip(points.par_iter())
        .for_each_init(
            || Vec::with_capacity(s),
            |found: &mut Vec<usize>, ((rows, offsets), &(b, p))| {
                found.clear();
                let centre_cell = [
                    ((p[2] - geometry.origin[2]) / size[2]).floor() as i64,
                    ((p[1] - geometry.origin[1]) / size[1]).floor() as i64,
                    ((p[0] - geometry.origin[0]) / size[0]).floor() as i64,
                ];
                'scan: for dz in -reach[0]..=reach[0] {
                    let z = centre_cell[0] + dz;
                    if z < 0 || z >= nz as i64 {
                        continue;
                    }
                    for dy in -reach[1]..=reach[1] {
                        let y = centre_cell[1] + dy;
                        if y < 0 || y >= ny as i64 {
                            continue;
                        }
                        let first_x = (centre_cell[2] - reach[2]).max(0);
                        let last_x = (centre_cell[2] + reach[2]).min(nx as i64 - 1);
                        if first_x > last_x {
                            continue;
                        }
                        let base = b * cells + (z as usize * ny + y as usize) * nx;
                        // The row's cells in x order, as a walk over dx would meet them.
                        let go_on = table.each_occupied(
                            base + first_x as usize,
                            base + last_x as usize,
                            |row| {
                                let c = centres[row as usize];
                                let d2 = (c[0] - p[0]).powi(2)
                                    + (c[1] - p[1]).powi(2)
                                    + (c[2] - p[2]).powi(2);
                                if d2 <= r2 {
                                    found.push(row as usize);
                                }
                                found.len() < s
                            },
                        );
                        if !go_on {
                            break 'scan;
                        }
                    }
                }
                for (j, (slot, offset)) in
                    rows.iter_mut().zip(offsets.chunks_exact_mut(3)).enumerate()
                {
                    // Unfilled slots repeat the first neighbour (a repeat does not change a max).
                    match found.get(j).or(found.first()) {
                        Some(&row) => {
                            *slot = row as i64;
                            let c = centres[row];
                            offset.copy_from_slice(&[
                                (c[0] - p[0]) as f32,
                                (c[1] - p[1]) as f32,
                                (c[2] - p[2]) as f32,
                            ]);
                        }
                        None => {
                            *slot = sentinel;
                            offset.fill(0.0);
                        }
                    }
                }
            },
        );
    let empty = rows
        .par_chunks(s.max(1))
        .filter(|r| r[0] == sentinel)
        .count();
    HostLevelIndex {
        rows,
        offsets,
        sentinel,
        empty,
    }
}

/// A linear layer without bias followed by batch norm.
#[derive(Module, Debug)]
pub struct LinearBn {
    pub linear: Linear,
    pub norm: BatchNorm,
}

impl LinearBn {
    pub fn new(channels: [usize; 2], device: &Device) -> Self {
        Self {
            linear: LinearConfig::new(channels[0], channels[1])
                .with_bias(false)
                .init(device),
            norm: batch_norm(channels[1], &HEAD_NORM, device),
        }
    }

    pub fn forward(&self, x: Tensor<2>) -> Tensor<2> {
        norm_rows(&self.norm, fusiondet_nn::linear::linear(&self.linear, x))
    }

    /// `relu(self.forward(x))`, the ReLU fused into the norm in training (`norm_rows_relu`).
    pub fn forward_relu(&self, x: Tensor<2>) -> Tensor<2> {
        norm_rows_relu(&self.norm, fusiondet_nn::linear::linear(&self.linear, x))
    }
}

/// One pooling level's layers.
#[derive(Module, Debug)]
pub struct PoolLevel {
    pub features: LinearBn,
    pub positions: LinearBn,
    pub out: LinearBn,
    #[module(skip)]
    pub samples: usize,
}

#[derive(Module, Debug)]
pub struct RoiGridPool {
    pub levels: Vec<PoolLevel>,
}

impl RoiGridPool {
    /// `channels[l]`: the feature width of level l's stage.
    pub fn new(config: &RoiHeadConfig, channels: &[usize], device: &Device) -> Self {
        let levels = config
            .levels
            .iter()
            .zip(channels)
            .map(|(l, &c)| PoolLevel {
                features: LinearBn::new([c, l.mid_channels], device),
                positions: LinearBn::new([3, l.mid_channels], device),
                out: LinearBn::new([l.mid_channels, l.out_channels], device),
                samples: l.samples,
            })
            .collect();
        Self { levels }
    }

    /// Pooled features [RoIs, grid points · Σ out channels], grid-point major.
    pub fn forward(&self, maps: &[&SparseMap], index: &RoiGridIndex) -> Tensor<2> {
        let points = index.num_rois * index.points_per_roi;
        let mut pooled = Vec::with_capacity(self.levels.len());
        for ((layer, map), level) in self.levels.iter().zip(maps).zip(&index.levels) {
            let device = map.features.device();
            let s = layer.samples;
            let features = layer.features.forward(map.features.clone());
            let [_, mid] = features.dims();
            // The appended zero row is what an empty neighbourhood gathers.
            let with_zero_row = |features: Tensor<2>| {
                Tensor::cat(vec![features, Tensor::zeros([1, mid], &device)], 0)
            };
            let summed = match level {
                LevelIndex::Host(level) if ragged::custom_path(&features) => {
                    // One pass each way for the gather + add and for the max (the same
                    // values and gradients as burn's operations below, to the bit).
                    let positions = layer.positions.forward(level.offsets_tensor(&device));
                    let rows = level.rows.iter().map(|&r| r as u32).collect();
                    let neighbours =
                        Arc::new(Neighbours::new(rows, s, level.sentinel as usize + 1));
                    let runs = Arc::new(Runs::blocks(points, s));
                    ragged::runs_max(
                        relu(ragged::gather_add(
                            with_zero_row(features),
                            positions,
                            &neighbours,
                        )),
                        &runs,
                    )
                }
                _ => {
                    let (gathered, offsets) = match level {
                        // On a GPU the gather's backward adds each voxel's readers in one
                        // thread (`RowGather`; the sentinel is its zero row), where burn's
                        // walks all rows per column.
                        LevelIndex::Host(level) => {
                            let rows: Vec<u32> = level.rows.iter().map(|&r| r as u32).collect();
                            let gather = RowGather::new(&rows, level.sentinel as usize, &device);
                            (gather.gather(features), level.offsets_tensor(&device))
                        }
                        // Made on the device, and turned around there where the network
                        // trains (the same readers, in the same order, as a host index's).
                        LevelIndex::Device(level) => {
                            let [rows, _] = features.dims();
                            let gather = RowGather::from_device_index(
                                level.rows.clone(),
                                rows,
                                &features.device(),
                            );
                            (gather.gather(features), level.offsets.clone())
                        }
                    };
                    let positions = layer.positions.forward(offsets);
                    relu(gathered + positions)
                        .reshape([points, s, mid])
                        .max_dim(1)
                        .reshape([points, mid])
                }
            };
            pooled.push(layer.out.forward_relu(summed));
        }
        let grid = Tensor::cat(pooled, 1);
        let [_, c] = grid.dims();
        grid.reshape([index.num_rois, index.points_per_roi * c])
    }

    /// Multiply-adds of one pass: the per-voxel layer over each level's sites, and the
    /// position and output layers over every grid point's neighbours.
    pub fn multiply_adds(&self, voxels: &[usize], grid_points: usize) -> u64 {
        self.levels
            .iter()
            .zip(voxels)
            .map(|(l, &n)| {
                let [c, mid] = l.features.linear.weight.dims();
                let [_, out] = l.out.linear.weight.dims();
                (n * c * mid + grid_points * l.samples * 3 * mid + grid_points * mid * out) as u64
            })
            .sum()
    }
}

/// The pooling level of the tests (here and in `roi_query_device`): stage 2 (stride 2),
/// cells 0.2 × 0.2 × 0.4 m, a 0.45 m radius that reaches past the nearest cells.
#[cfg(test)]
pub(super) fn test_level() -> (VoxelGeometry, PoolLevelConfig) {
    let geometry = VoxelGeometry {
        origin: [0.0, -2.0, -1.0],
        voxel_size: [0.1, 0.1, 0.2],
    };
    let level = PoolLevelConfig {
        stage: 2,
        mid_channels: 4,
        out_channels: 3,
        query_range: [2, 3, 3],
        radius: 0.45,
        samples: 5,
    };
    (geometry, level)
}

#[cfg(test)]
mod tests {
    use super::super::synthetic::unit;
    use super::*;
    use std::sync::Arc;

    #[test]
    fn the_query_check_finds_the_grid_points_whose_rows_differ() {
        // Two grid points of 2 samples; the second's rows differ on the "device".
        let host = HostLevelIndex {
            rows: vec![3, 1, 7, 7],
            offsets: vec![0.1, 0.2, 0.3, 0.0, 0.1, 0.0, 0.5, 0.5, 0.5, 0.5, 0.5, 0.5],
            sentinel: 9,
            empty: 0,
        };
        let device = Device::flex();
        let on_device = |rows: Vec<i64>, offsets: Vec<f32>| DeviceLevelIndex {
            rows: Tensor::from_data(TensorData::new(rows, [4]), &device),
            offsets: Tensor::from_data(TensorData::new(offsets, [4, 3]), &device),
        };
        let mut offsets = host.offsets.clone();
        offsets[1] += 1e-3;
        let c = compare_levels(&host, &on_device(vec![3, 1, 7, 2], offsets.clone()), 2);
        assert_eq!(c.grid_points, 2);
        assert_eq!(c.differing, 1);
        assert_eq!(c.first, Some((1, vec![7, 7], vec![7, 2])));
        assert!((c.max_offset_difference - 1e-3).abs() < 1e-6);
        let same = compare_levels(
            &host,
            &on_device(host.rows.clone(), host.offsets.clone()),
            2,
        );
        assert_eq!((same.differing, same.max_offset_difference), (0, 0.0));
        // An index of another length differs everywhere.
        let short = DeviceLevelIndex {
            rows: Tensor::from_data(TensorData::new(vec![3i64, 1], [2]), &device),
            offsets: Tensor::from_data(TensorData::new(vec![0f32; 6], [2, 3]), &device),
        };
        assert_eq!(compare_levels(&host, &short, 2).differing, 2);
        // Rows no query writes are counted.
        let wild = compare_levels(&host, &on_device(vec![3, -5, 7, 10], offsets), 2);
        assert_eq!((wild.differing, wild.out_of_range), (2, 2));
        assert_eq!(same.out_of_range, 0);
    }

    #[test]
    fn the_query_runs_on_the_host_for_the_cpu() {
        assert_eq!(query_place(&Device::flex()), QueryPlace::Host);
    }

    fn matrix(t: Tensor<2>) -> Vec<Vec<f32>> {
        let [_, c] = t.dims();
        let v = t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap();
        v.chunks(c).map(<[f32]>::to_vec).collect()
    }

    /// x W followed by inference batch norm, from the layer's own tensors.
    fn linear_bn(layer: &LinearBn, x: &[f32]) -> Vec<f32> {
        let w = matrix(layer.linear.weight.val());
        let vec1 = |t: Tensor<1>| t.into_data().convert::<f32>().try_to_vec::<f32>().unwrap();
        let (gamma, beta) = (vec1(layer.norm.gamma.val()), vec1(layer.norm.beta.val()));
        let (mean, var) = (
            vec1(layer.norm.running_mean.value()),
            vec1(layer.norm.running_var.value()),
        );
        let eps = layer.norm.epsilon as f32;
        (0..w[0].len())
            .map(|o| {
                let y: f32 = x.iter().zip(&w).map(|(a, row)| a * row[o]).sum();
                (y - mean[o]) / (var[o] + eps).sqrt() * gamma[o] + beta[o]
            })
            .collect()
    }

    /// The kept cell tables: a query sees exactly its own sites (a second query over other
    /// sites and a smaller grid gets what fresh tables give), and the tables are empty again
    /// after a query, also one that panicked.
    #[test]
    fn the_kept_cell_table_holds_only_the_current_sites() {
        let (geometry, level) = test_level();
        let sites = |seed: u64, count: usize, shape: [usize; 3]| {
            let mut state = seed;
            let mut coords = Vec::new();
            while coords.len() < count {
                let c = [
                    0,
                    (unit(&mut state) * shape[0] as f64) as i32,
                    (unit(&mut state) * shape[1] as f64) as i32,
                    (unit(&mut state) * shape[2] as f64) as i32,
                ];
                if !coords.contains(&c) {
                    coords.push(c);
                }
            }
            SparseSites::new(coords, shape, 1).unwrap()
        };
        let roi = [1.0, 0.0, 0.2, 1.6, 1.0, 0.8, 0.4];
        let points: Vec<(usize, [f64; 3])> = roi_grid_points(&roi, 3)
            .into_iter()
            .map(|p| (0, p))
            .collect();
        let (many, few) = (sites(3, 400, [6, 20, 20]), sites(5, 60, [5, 16, 18]));
        let mut kept = CellTable::empty();
        let query = |table: &mut CellTable, s: &SparseSites| {
            query_level_with(table, &points, s, &level, &geometry).rows
        };
        let fresh = query(&mut CellTable::empty(), &few);
        query(&mut kept, &many);
        assert_eq!(query(&mut kept, &few), fresh);
        // The kept tables themselves, as the process-wide ones are used.
        assert_eq!(query_level(&points, &few, &level, &geometry).rows, fresh);
        let panicked = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
            with_cells_in(&mut kept, 8, [(3, 7), (5, 1)].into_iter(), |_| {
                panic!("a failed query")
            })
        }));
        assert!(panicked.is_err());
        assert!(kept.rows.iter().all(|&row| row == -1), "{:?}", kept.rows);
        assert!(kept.occupied.iter().all(|&bits| bits == 0));
    }

    /// The occupied cells of a range in ascending order across word boundaries, and the
    /// walk stopped when asked.
    #[test]
    fn occupied_cells_are_met_in_order() {
        let set = [(0, 10), (63, 11), (64, 12), (130, 13), (199, 14)];
        with_cells_in(&mut CellTable::empty(), 200, set.into_iter(), |cells| {
            let within = |first, last| {
                let mut rows = Vec::new();
                cells.each_occupied(first, last, |row| {
                    rows.push(row);
                    true
                });
                rows
            };
            assert_eq!(within(0, 199), [10, 11, 12, 13, 14]);
            assert_eq!(within(1, 63), [11]);
            assert_eq!(within(64, 64), [12]);
            assert_eq!(within(65, 129), Vec::<i32>::new());
            assert_eq!(within(63, 130), [11, 12, 13]);
            let mut met = Vec::new();
            let finished = cells.each_occupied(0, 199, |row| {
                met.push(row);
                met.len() < 2
            });
            assert!(!finished);
            assert_eq!(met, [10, 11]);
        });
    }

    /// The query and the pooled features by brute force: every site of the level tested
    /// against every grid point, neighbours ordered by their (dz, dy, dx) cell offset.
    #[test]
    fn pooling_matches_a_brute_force_reference() {
        let device = Device::flex();
        let mut state = 7u64;
        let (geometry, level) = test_level();
        // Stage 2 (stride 2): cells 0.2 × 0.2 × 0.4 m over a [6, 20, 20] grid, 2 items.
        let shape = [6, 20, 20];
        let mut coords = Vec::new();
        while coords.len() < 500 {
            let c = [
                (unit(&mut state) * 2.0) as i32,
                (unit(&mut state) * 6.0) as i32,
                (unit(&mut state) * 20.0) as i32,
                (unit(&mut state) * 20.0) as i32,
            ];
            if !coords.contains(&c) {
                coords.push(c);
            }
        }
        let sites = Arc::new(SparseSites::new(coords, shape, 2).unwrap());
        let channels = 6;
        let feats: Vec<f32> = (0..sites.len() * channels)
            .map(|_| unit(&mut state) as f32 - 0.5)
            .collect();
        let map = SparseMap {
            features: Tensor::from_data(
                TensorData::new(feats.clone(), [sites.len(), channels]),
                &device,
            ),
            sites: sites.clone(),
        };
        // Two RoIs in item 0, one in item 1 (one partly outside the grid).
        let rois = vec![
            vec![
                [2.0, 0.0, 0.2, 1.6, 1.0, 0.8, 0.4],
                [0.3, -1.8, 0.0, 1.0, 1.0, 1.0, -1.2],
            ],
            vec![[1.5, 0.5, 0.5, 2.0, 1.2, 1.0, 2.0]],
        ];
        let grid = 3;
        let index = RoiGridIndex::new(
            &rois,
            &[&sites],
            std::slice::from_ref(&level),
            grid,
            &geometry,
        );
        let config = RoiHeadConfig {
            grid_size: grid,
            levels: vec![level.clone()],
            ..RoiHeadConfig::default()
        };
        let pool = RoiGridPool::new(&config, &[channels], &device);
        let out = matrix(pool.forward(&[&map], &index));

        let layer = &pool.levels[0];
        let size = geometry.level_voxel_size(2);
        let mut empties = 0;
        for (b, list) in rois.iter().enumerate() {
            for (r, roi) in list.iter().enumerate() {
                let roi_row = rois[..b].iter().map(Vec::len).sum::<usize>() + r;
                for (g, p) in roi_grid_points(roi, grid).iter().enumerate() {
                    let cell =
                        [2, 1, 0].map(|a| ((p[a] - geometry.origin[a]) / size[a]).floor() as i64);
                    let mut near: Vec<([i64; 3], usize)> = sites
                        .coords()
                        .iter()
                        .enumerate()
                        .filter(|(_, c)| c[0] as usize == b)
                        .filter_map(|(row, c)| {
                            let d = [0, 1, 2].map(|a| c[a + 1] as i64 - cell[a]);
                            let centre = geometry.voxel_centre([c[1], c[2], c[3]], 2);
                            let d2: f64 = (0..3).map(|a| (centre[a] - p[a]).powi(2)).sum();
                            let inside = (0..3)
                                .all(|a| d[a].unsigned_abs() as usize <= level.query_range[a]);
                            (inside && d2 <= level.radius * level.radius).then_some((d, row))
                        })
                        .collect();
                    near.sort();
                    near.truncate(level.samples);
                    let mut pooled = vec![f32::NEG_INFINITY; level.mid_channels];
                    if near.is_empty() {
                        empties += 1;
                        let pos = linear_bn(&layer.positions, &[0.0; 3]);
                        for (m, v) in pooled.iter_mut().zip(pos) {
                            *m = v.max(0.0);
                        }
                    }
                    for &(_, row) in &near {
                        let f = linear_bn(
                            &layer.features,
                            &feats[row * channels..(row + 1) * channels],
                        );
                        let c = geometry.voxel_centre(
                            [
                                sites.coords()[row][1],
                                sites.coords()[row][2],
                                sites.coords()[row][3],
                            ],
                            2,
                        );
                        let rel = [0, 1, 2].map(|a| (c[a] - p[a]) as f32);
                        let pos = linear_bn(&layer.positions, &rel);
                        for ((m, a), q) in pooled.iter_mut().zip(f).zip(pos) {
                            *m = m.max((a + q).max(0.0));
                        }
                    }
                    let expected: Vec<f32> = linear_bn(&layer.out, &pooled)
                        .into_iter()
                        .map(|v| v.max(0.0))
                        .collect();
                    let got = &out[roi_row][g * 3..g * 3 + 3];
                    for (e, v) in expected.iter().zip(got) {
                        assert!(
                            (e - v).abs() < 1e-4,
                            "roi {roi_row} point {g}: {got:?} vs {expected:?}"
                        );
                    }
                }
            }
        }
        assert_eq!(index.levels[0].host().unwrap().empty, empties);
        assert!(
            empties > 0 && empties < 3 * 27,
            "the case has both empty and filled neighbourhoods: {empties}"
        );
    }
}
